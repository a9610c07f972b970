"""Scenes from TOML files or dictionaries, and `--set section.key=value` overrides."""

from __future__ import annotations

import tomllib
from dataclasses import fields
from pathlib import Path
from typing import Any

from .. import formats
from ..errors import InputError
from .body import FixedRegion, Material, MeshSpec, Removal, Swelling
from .checks import did_you_mean
from .loads import Fluid, Gravity
from .numerics import Damping, Element, Output, SolverConfig, TimeScheme
from .scene import Scene
from .septum import SeptumSpec
from .skull import Skull

# ---------------------------------------------------------------- TOML loading
_SECTIONS = {
    "mesh": MeshSpec,
    "material": Material,
    "gravity": Gravity,
    "fluid": Fluid,
    "skull": Skull,
    "time": TimeScheme,
    "damping": Damping,
    "solver": SolverConfig,
    "element": Element,
    "output": Output,
}


def _build(cls, table: Any, where: str):
    if not isinstance(table, dict):
        raise InputError(f"{where} must be a table")
    known = [f.name for f in fields(cls) if f.repr]  # (parsed forms such as a predicate are not keys)
    for key in table:
        if key not in known:
            raise InputError(f"{where} unknown key '{key}';{did_you_mean(key, known)} known keys: {', '.join(known)}")
    try:
        return cls(**table)
    except TypeError as exc:  # a value of the wrong kind deep inside
        raise InputError(f"{where} {exc}") from None


def scene_from_dict(data: dict, base: Path | None = None) -> Scene:
    """Build a Scene from parsed TOML; relative mesh files resolve against ``base``."""
    known = list(_SECTIONS) + ["fixed", "remove", "swelling", "septum", "probes", "surfaces", "name"]
    for key in data:
        if key not in known:
            raise InputError(f"unknown section [{key}];{did_you_mean(key, known)} known sections: {', '.join(known)}")
    for required in ("mesh", "material"):
        if required not in data:
            raise InputError(f"missing section [{required}]")
    kwargs: dict[str, Any] = {
        name: _build(cls, data[name], f"[{name}]") for name, cls in _SECTIONS.items() if name in data
    }
    fixed = data.get("fixed", [])
    if not isinstance(fixed, list):
        raise InputError('[[fixed]] must be an array of tables: [[fixed]] where = "z < 0.001"')
    kwargs["fixed"] = tuple(_build(FixedRegion, f, "[[fixed]]") for f in fixed)
    remove = data.get("remove", [])
    if not isinstance(remove, list):
        raise InputError('[[remove]] must be an array of tables: [[remove]] at = 10.0, where = "..."')
    kwargs["remove"] = tuple(_build(Removal, r, "[[remove]]") for r in remove)
    swelling = data.get("swelling", [])
    if not isinstance(swelling, list):
        raise InputError('[[swelling]] must be an array of tables: [[swelling]] where = "...", volume_change = -0.02')
    kwargs["swelling"] = tuple(_build(Swelling, r, "[[swelling]]") for r in swelling)
    septa = data.get("septum", [])
    if not isinstance(septa, list):
        raise InputError(
            '[[septum]] must be an array of tables: [[septum]] name = "falx", point = [0, 0, 0], normal = [1, 0, 0]'
        )
    septa = [
        _build(
            SeptumSpec,
            {"name": f"septum{i + 1}", **r} if isinstance(r, dict) else r,
            f"[[septum]] {r.get('name', f'septum{i + 1}') if isinstance(r, dict) else i + 1}",
        )
        for i, r in enumerate(septa)
    ]
    for septum in septa:
        if septum.file is not None:
            if base is not None and not Path(septum.file).is_absolute():
                septum.file = str((base / septum.file).resolve())
            if not Path(septum.file).is_file():
                raise InputError(f"[[septum]] {septum.title} file not found: {septum.file}")
    names = [s.name for s in septa if s.name is not None]
    if len(set(names)) != len(names):
        raise InputError(f"[[septum]] names must differ (got {', '.join(names)})")
    kwargs["septa"] = tuple(s for s in septa if s.enabled)
    probes = data.get("probes", {})
    if not isinstance(probes, dict):
        raise InputError("[probes] must be a table of name = [x, y, z]")
    kwargs["probes"] = _with_markups(dict(probes), base)
    surfaces = data.get("surfaces", {})
    if not isinstance(surfaces, dict):
        raise InputError('[surfaces] must be a table of name = "condition on x, y, z"')
    kwargs["surfaces"] = surfaces
    if "name" in data:
        if not isinstance(data["name"], str):
            raise InputError("name must be a string")
        kwargs["name"] = data["name"]
    mesh = kwargs["mesh"]
    if base is not None:
        if mesh.file is not None and not Path(mesh.file).is_absolute():
            mesh.file = str((base / mesh.file).resolve())
        if mesh.surface is not None and not Path(mesh.surface).is_absolute():
            mesh.surface = str((base / mesh.surface).resolve())
        skull = kwargs.get("skull")
        if skull is not None and skull.file is not None and not Path(skull.file).is_absolute():
            skull.file = str((base / skull.file).resolve())
    skull = kwargs.get("skull")
    if skull is not None and skull.file is not None and not Path(skull.file).is_file():
        raise InputError(f"[skull] file not found: {skull.file}")
    check_mesh_files(mesh)
    return Scene(**kwargs)


# keys naming a file: in a scene file relative to its folder, in an override to the current one
FILE_KEYS = ("mesh.file", "mesh.surface", "skull.file", "probes.markups")


def apply_override(data: dict, assignment: str) -> None:
    """Apply ``section.key=value`` (``fixed.0.where=...`` indexes arrays, ``septum.falx.enabled``
    names an entry by its ``name``) to parsed TOML.

    The value is read as a TOML value (numbers, booleans, strings, arrays); a bare word that
    is not valid TOML is taken as a string, so ``solver.kind=cholesky`` works unquoted."""
    key, sep, text = assignment.partition("=")
    if not sep or not key.strip():
        raise InputError(f"--set '{assignment}': expected section.key=value, e.g. time.end=2.0")
    try:
        value = tomllib.loads(f"v = {text.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = text.strip()
    if (key.strip() in FILE_KEYS or key.strip().startswith("septum.") and key.strip().endswith(".file")) and isinstance(
        value, str
    ):
        value = str(Path(value).resolve())  # typed in a shell: relative to where it was typed
    node: Any = data
    parts = key.strip().split(".")
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, list):
            named = [j for j, entry in enumerate(node) if isinstance(entry, dict) and entry.get("name") == part]
            if named:
                part = str(named[0])
            if not part.isdigit() or int(part) >= len(node):
                names = [
                    entry["name"] for entry in node if isinstance(entry, dict) and isinstance(entry.get("name"), str)
                ]
                known = f" or a name ({', '.join(names)})" if names else ""
                raise InputError(f"--set '{key}': '{part}' is not an index of that array (0..{len(node) - 1}){known}")
            if last:
                node[int(part)] = value
            else:
                node = node[int(part)]
        elif isinstance(node, dict):
            if last:
                node[part] = value
            else:
                node = node.setdefault(part, {})
        else:
            raise InputError(f"--set '{key}': '{'.'.join(parts[:i])}' is a value, not a table")


def load_scene(path: str | Path, overrides: list[str] = ()) -> Scene:
    """Read and validate a scene file, or a bundled scene by name ("cube", "brain", ...: see
    ``brainshift scenes``); every problem is a one-line InputError. ``overrides`` are
    ``section.key=value`` strings applied before validation."""
    data, base = scene_data(path, overrides)
    return scene_from_dict(data, base=base)


def scene_data(path: str | Path, overrides: list[str] = ()) -> tuple[dict, Path]:
    """(the scene file's TOML as a dict with the overrides applied, the folder its relative
    paths start from), not yet validated."""
    from ..data import bundled_scene

    path = Path(path)
    if not path.is_file():
        bundled = bundled_scene(str(path))
        if bundled is None:
            from ..data import scene_names

            hint = did_you_mean(path.name, scene_names()) if path.parent == Path(".") else ""
            raise InputError(
                f"scene file '{path}' not found"
                + (f";{hint}" if hint else "")
                + " (bundled scenes: `brainshift scenes`)"
            )
        path = bundled
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path.name}: not valid TOML ({exc})") from None
    for assignment in overrides:
        apply_override(data, assignment)
    return data, path.parent


def _with_markups(probes: dict, base: Path | None) -> dict:
    """``[probes] markups = "points.mrk.json"``: every control point of a 3D Slicer point list
    becomes a probe named by its label, at its RAS position (mm in the file, m in the scene)."""
    if "markups" not in probes:
        return probes
    name = probes.pop("markups")
    if not isinstance(name, str):
        raise InputError("[probes] markups must be the name of a Slicer point list (.mrk.json)")
    path = Path(name) if base is None or Path(name).is_absolute() else (base / name).resolve()
    from ..images.frames import read_markups

    labels, points = read_markups(path, "[probes] markups")
    for label, point in zip(labels, points):
        key = label
        while key in probes:  # two points of one name keep both
            key += "'"
        probes[key] = [float(c) * 1e-3 for c in point]
    return probes


def check_mesh_files(mesh: MeshSpec) -> None:
    """[mesh] file and surface exist and have a suffix the package reads."""
    for key in ("file", "surface"):
        name = getattr(mesh, key)
        if name is None:
            continue
        if not Path(name).is_file():
            raise InputError(f"[mesh] {key} '{name}' not found; give a path relative to the scene file")
        if not formats.is_mesh_input(name) or (key == "surface" and not formats.is_voxelizable(name)):
            raise InputError(f"[mesh] {key} '{Path(name).name}': {formats.MESH_HELP}")
