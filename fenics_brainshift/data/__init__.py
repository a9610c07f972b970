"""What ships with the package: the demo scenes and the bundled MNI brain they use.

``scenes/*.toml`` refer to ``meshes/`` by relative paths, so they work from the source tree
and from an installed wheel alike; `brainshift run cube` finds them by name. In the source
tree ``meshes/`` is a link to the repository's top-level meshes/ folder; a wheel carries the
files themselves (setuptools copies what the link points to).
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
SCENES = HERE / "scenes"
MESHES = HERE / "meshes"


def scene_names() -> list[str]:
    """Names of the bundled scenes (the file names without .toml)."""
    return sorted(p.stem for p in SCENES.glob("*.toml"))


def bundled_scene(name: str) -> Path | None:
    """The bundled scene file of that name ("cube" or "cube.toml"), or None."""
    path = SCENES / (name if name.endswith(".toml") else f"{name}.toml")
    return path if "/" not in name and path.is_file() else None


def scene_path(name: str) -> Path:
    """The bundled scene file of that name; KeyError naming the choices if there is none."""
    path = bundled_scene(name)
    if path is None:
        raise KeyError(f"no bundled scene '{name}'; bundled: {', '.join(scene_names())}")
    return path
