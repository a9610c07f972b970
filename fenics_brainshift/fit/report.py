"""What a fit writes: the fitted scene (TOML a user runs again) and fit.json."""

from __future__ import annotations

import os
from pathlib import Path

from ..outputs.files import write_json
from ..scene.toml import scene_data

FILE_KEYS = (("mesh", "file"), ("mesh", "surface"), ("skull", "file"), ("probes", "markups"))


def write_fitted_scene(scene_path, overrides: list[str], changes: dict, out: Path) -> Path:
    """The scene file with the command line's overrides and the fitted values in, its relative
    file names made absolute (the fitted file lives elsewhere). changes: {"section.key": value},
    value None removes the key."""
    import tomli_w

    data, base = scene_data(scene_path, overrides)
    for section, key in FILE_KEYS:
        table = data.get(section)
        if isinstance(table, dict) and isinstance(table.get(key), str) and not Path(table[key]).is_absolute():
            table[key] = str((base / table[key]).resolve())
    for dotted, value in changes.items():
        section, key = dotted.split(".", 1)
        table = data.setdefault(section, {})
        if value is None:
            table.pop(key, None)
        else:
            table[key] = value
    # its run goes where the fit wrote it, not over the scene's own folder (out_brain)
    data.setdefault("output", {})["folder"] = str(Path(out).resolve())
    path = out / "fitted.toml"
    tmp = path.with_suffix(".toml.tmp")
    tmp.write_text(
        "# written by brainshift fit: the scene with the fitted parameters (fit.json says how well)\n"
        + tomli_w.dumps(data)
    )
    os.replace(tmp, path)
    return path


def write_fit_json(out: Path, result, target, comm, surface: str | None = None) -> Path:
    """fit.json; ``surface``: what point-to-surface distances were measured to."""
    data = {
        "target": {"kind": target.kind, "points": len(target.measured), "labels": target.labels},
        **result.as_dict(),
    }
    if target.pre is None and surface is not None:
        data["target"]["measured_to"] = surface
    write_json(out / "fit.json", data, comm)
    return out / "fit.json"
