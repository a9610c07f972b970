"""What the dural septa cost a settled state: the bundled brain after the drain (follower CSF
load) with its falx and tentorium and one shrinking region, against the same state without
them, linear and neo-Hookean, in one run.

    .venv/bin/python benchmarks/septa.py [--voxel 0.005]   # writes benchmarks/results/septa.md

Cases: none; the septa alone; the septa and the whole brain shrinking by 2 % (a hyperosmotic
drug). Each: setup (mesh, model with the septa's nodes and projector, factor) and the settled
state at the end of the drain, the median of REPEATS runs taken in turn with the others; the
ratios are against the same model without either.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
from pathlib import Path

import swelling  # its settled state, timed (this folder is on the path when run as a script)

from fenics_brainshift import logs
from fenics_brainshift.scene import Swelling

ROOT = Path(__file__).resolve().parents[1]
REPEATS = swelling.REPEATS
SEPTA = ["septum.falx.enabled=true", "septum.tentorium.enabled=true"]
REGIONS = {  # (overrides, swelling)
    "none": ([], ()),
    "falx + tentorium": (SEPTA, ()),
    "falx + tentorium, whole brain -2 %": (SEPTA, (Swelling(volume_change=-0.02, where="x > -1"),)),
}


def settle(voxel: float, model: str, case) -> tuple[float, float, int, float]:
    """(setup s, settled-state s, linear solves, frontal pole |u| mm)."""
    overrides, regions = case
    return swelling.settle(voxel, model, regions, overrides)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--voxel", type=float, default=0.005)
    args = p.parse_args(argv)
    logs.configure("WARNING")
    cases, runs = swelling.timed_runs(REGIONS, settle, args.voxel, 0.015)
    lines = [
        f"# What the dural septa cost a settled state: the bundled brain, {args.voxel * 1e3:g} mm voxels",
        "",
        f"`.venv/bin/python benchmarks/septa.py --voxel {args.voxel:g}`; {platform.processor() or platform.machine()}, "
        f"one rank; the settled state after the drain (follower CSF load); medians of {REPEATS} runs taken in turn; "
        f"ratios against the same model without septa or swelling. Setup: mesh, model (the septa's nodes and "
        f"projector), the factor of K.",
        "",
        "| model | case | setup (s) | settled state (s) | settled against none | setup + settled against none "
        "| linear solves | frontal pole (mm) |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for model, region in cases:
        setup, solve, solves, pole = (statistics.median(v) for v in zip(*runs[(model, region)]))
        base = [statistics.median(r[i] for r in runs[(model, "none")]) for i in (0, 1)]
        lines.append(
            f"| {model} | {region} | {setup:.2f} | {solve:.2f} | {solve / base[1]:.2f}x | "
            f"{(setup + solve) / sum(base):.2f}x | {solves:.0f} | {pole:.2f} |"
        )
        print(lines[-1], flush=True)
    out = ROOT / "benchmarks" / "results" / "septa.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
