"""`brainshift atlas SCENE -o ATLAS`: before surgery, the settled states of a scene over drain
levels, head poses and swelling (atlas/build.py), written for `brainshift update`."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..atlas.resection import DEFAULT_STAGES
from ..errors import InputError
from .help_format import Defaults


def add(sub) -> None:
    atlas = sub.add_parser(
        "atlas",
        formatter_class=Defaults,
        help="before surgery: the settled states of a scene over drain levels, head poses "
        "and swelling (docs/update.md)",
        description="Solve the scene's settled states over a family of scenarios (fluid.level x "
        "head pose: convex weights in the update) and one perturbation per swelling "
        "region (bounded amplitudes); writes "
        "ATLAS/atlas.h5 and ATLAS/atlas.json.",
    )
    atlas.add_argument("scene", help="scene file or bundled scene name")
    atlas.add_argument("-o", "--output", required=True, help="atlas folder")
    atlas.add_argument(
        "--vary",
        action="append",
        default=[],
        metavar="KEY=VALUES",
        help="fluid.level=0.02,0.03 or 0.01:0.05:5 (m), gravity.angle_x|y|z=-10,0,10 (degrees), "
        "material.G=LOW,HIGH (Pa), swelling.N=LOW,HIGH (volume change of region N); default: 14 "
        "levels x 25 poses, G from a third to three times the scene's",
    )
    atlas.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="scene overrides")
    atlas.add_argument(
        "--resect",
        default=None,
        metavar="REGION",
        help="the tumour to take out in stages, from the craniotomy inwards: label=N (or a segment's name) of "
        'the scene\'s label volume, or a condition on the cell centroid ("(x-0.02)**2 + ... < 0.01**2", m); '
        "default: the scene's [[remove]], if any (docs/update.md, Resection)",
    )
    atlas.add_argument(
        "--stages",
        type=int,
        default=None,
        help=f"the resection's stages, each a fraction of the region's volume, the deepest last (default "
        f"{DEFAULT_STAGES}); each costs about what the atlas before the resection costs",
    )
    atlas.add_argument(
        "--ranks-per-mode",
        type=int,
        default=None,
        help="under mpirun: how many ranks solve each mode together (default 1: every rank solves whole "
        "poses on its own copy of the model; more where one rank's memory cannot hold it); a divisor of -n",
    )


def arguments(scene: str, output, vary: list[str], sets: list[str]) -> argparse.Namespace:
    """`brainshift atlas SCENE -o OUTPUT --vary ... --set ...` as this command's parser makes
    it, every other option its default (for a benchmark that calls main in process)."""
    parser = argparse.ArgumentParser()
    add(parser.add_subparsers())
    words = ["atlas", scene, "-o", str(output)]
    words += [w for v in vary for w in ("--vary", v)] + [w for s in sets for w in ("--set", s)]
    return parser.parse_args(words)


def main(args, comm) -> list[str]:
    """Build the atlas and write it; returns the report's lines."""
    from ..atlas import store
    from ..atlas.build import build
    from ..atlas.groups import check as check_groups
    from ..atlas.resection import parse_resect
    from ..atlas.scenarios import parse_vary
    from ..outputs.files import RunLock, check_writable
    from ..scene import load_scene

    out = Path(args.output)
    check_writable(out, comm, "atlas folder", "-o")
    check_groups(comm.size, args.ranks_per_mode)
    vary = parse_vary(args.vary)
    scene = load_scene(args.scene, args.set + ["time.mode=quasi-static"])
    if scene.skull is not None and scene.skull.glue is not None:
        raise InputError(
            "atlas: a [skull] with glue (fixed_where) holds the body by contact: give the support as [[fixed]] instead"
        )
    resection = parse_resect(args.resect, scene.remove, args.stages)
    if resection is not None and scene.fluid is not None and scene.fluid.rule == "quadrature":
        raise InputError(
            'atlas --resect: the fluid must act on the cavity\'s walls too: use [fluid] rule = "consistent" '
            '("quadrature" acts on the original surface only)'
        )
    created = comm.bcast(not out.exists(), root=0)
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    lock = RunLock(out, comm, "-o")  # (two builds into one folder would interleave their files)
    try:
        atlas, seconds = build(scene, vary, comm, args.scene, args.set, args.ranks_per_mode, resection)
        if comm.rank == 0:  # (arrays first, then the index: each renamed into place)
            store.write(out, atlas)
        comm.barrier()
    except BaseException:
        lock.release()
        if created and comm.rank == 0:  # (no folder left behind that holds nothing but the lock)
            (out / RunLock.NAME).unlink(missing_ok=True)
            if not any(out.iterdir()):
                out.rmdir()
        raise
    lock.release()
    family_count = int(atlas.family.sum()) if comm.rank == 0 else 0
    left_out = atlas.info["left_out"] if comm.rank == 0 else []
    levels = (
        sorted({s["values"]["fluid.level"] for s in atlas.scenarios if "fluid.level" in s.get("values", {})})
        if comm.rank == 0
        else []
    )
    drained = (atlas.info.get("prior") or {}).get("fluid.level") if comm.rank == 0 else None
    span = (
        [
            f"  levels {levels[0]:.4g} to {levels[-1]:.4g} m along up: {(levels[0] - drained) * 1e3:+.0f} to "
            f"{(levels[-1] - drained) * 1e3:+.0f} mm about the scene's drained level {drained:.4g} m"
        ]
        if levels and drained is not None
        else []
    )
    return (
        [
            f"atlas: {len(atlas.scenarios) if comm.rank == 0 else 0} modes ({family_count} drain/pose "
            f"scenarios, {len(atlas.scenarios) - family_count if comm.rank == 0 else 0} swelling) of "
            f"'{scene.name}' in {seconds['modes_s']:.1f} s after a {seconds['setup_s']:.1f} s setup; wrote "
            f"{out}/atlas.h5 and atlas.json"
        ]
        + (
            [
                f"warning: {len(left_out)} scenario(s) left out, settled neither from the last mode nor from rest "
                f'(atlas.json "left_out"): {", ".join(str(o["values"]) for o in left_out[:3])}'
            ]
            if left_out
            else []
        )
        + span
        + (_stage_lines(atlas, out) if comm.rank == 0 and atlas.stages else [])
    )


def _stage_lines(atlas, out: Path) -> list[str]:
    """A line a resection stage: what it removed and what it cost."""
    count = len(atlas.stages)
    lines = [f"  resection of {atlas.info['resection']['region']} in {count} stage{'s' * (count > 1)} ({out}/stages/):"]
    for stage in atlas.stages:
        s = stage.info["stage"]
        lines.append(
            f"    stage {s['number']}: {s['removed_ml']:.1f} ml removed ({s['cells']} cells"
            + (f", {s['free_cells']} cut free with them" if s.get("free_cells") else "")
            + f"), {len(stage.scenarios)} modes in {stage.info['modes_s']:.1f} s"
        )
    return lines
