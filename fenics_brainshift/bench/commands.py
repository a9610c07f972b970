"""A command's arguments as its own parser makes them, for a benchmark that calls it in process."""

from __future__ import annotations

import argparse
from pathlib import Path


def atlas_arguments(scene: str, output: Path, vary: list[str], sets: list[str]) -> argparse.Namespace:
    """`brainshift atlas SCENE -o OUTPUT --vary ... --set ...`, every other option its default."""
    from ..commands import atlas

    parser = argparse.ArgumentParser()
    atlas.add(parser.add_subparsers())
    words = ["atlas", scene, "-o", str(output)]
    words += [w for v in vary for w in ("--vary", v)] + [w for s in sets for w in ("--set", s)]
    return parser.parse_args(words)
