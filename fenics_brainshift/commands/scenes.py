"""`brainshift scenes`: the bundled scenes, by name and file."""

from __future__ import annotations


def add(sub) -> None:
    sub.add_parser("scenes", help="the bundled scenes (run one by name: brainshift run cube)")


def main(args, comm) -> list[str]:
    """One line per bundled scene: its name and its file."""
    from ..data import scene_names, scene_path

    return [f"{name:10s} {scene_path(name)}" for name in scene_names()]
