"""What a [[swelling]] costs a settled state: the bundled brain after the drain (follower CSF
load) with and without one region that shrinks or swells, linear and neo-Hookean, in one run.

    .venv/bin/python benchmarks/swelling.py [--voxel 0.005]   # writes benchmarks/results/swelling.md

Regions: the whole brain shrinking by 2 % (a hyperosmotic drug), and oedema swelling 5 % in a
sphere of 20 mm around a point of the right frontal lobe. Each case: setup (mesh, model,
factor) and the settled state at the end of the drain, the median of REPEATS runs taken in
turn with the others; the ratio is against the same model without swelling.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_brainshift import load_scene, logs
from fenics_brainshift.runner import Simulation
from fenics_brainshift.scene import Swelling

ROOT = Path(__file__).resolve().parents[1]
REPEATS = 3
REGIONS = {
    "none": (),
    "whole brain -2 %": (Swelling(volume_change=-0.02, where="x > -1"),),
    "oedema +5 %, 20 mm sphere": (
        Swelling(volume_change=0.05, where="(x - 0.03)**2 + (y - 0.03)**2 + (z - 0.02)**2 < 0.02**2"),
    ),
}


def settle(voxel: float, model: str, regions, overrides=()) -> tuple[float, float, int, float]:
    """(setup s, settled-state s, linear solves, frontal pole |u| mm) of the brain with these
    [[swelling]] regions and scene overrides (benchmarks/septa.py uses it too)."""
    scene = load_scene(
        "brain",
        [
            f"mesh.voxel={voxel}",
            "time.mode=quasi-static",
            f"material.model={model}",
            "output.pictures=false",
            *overrides,
        ],
    )
    scene.swelling = regions
    t0 = time.perf_counter()
    sim = Simulation(scene, MPI.COMM_WORLD)
    sim.setup()
    t1 = time.perf_counter()
    sim.solve_to_settled(scene.fluid.schedule.times[-1])
    t2 = time.perf_counter()
    pole = float(np.linalg.norm(sim.probe_values()[0]) * 1e3)
    solves = sim.solves.count
    sim.destroy()
    return t1 - t0, t2 - t1, solves, pole


def timed_runs(regions: dict, settle, voxel: float, warm_voxel: float) -> tuple[list, dict]:
    """(cases, {case: [settle's result per repeat]}) for both models and every region, the
    repeats taken in turn; the form compiler's cache warmed first on a coarse mesh."""
    cases = [(m, r) for m in ("linear", "neo-hookean") for r in regions]
    for model, region in cases:
        settle(warm_voxel, model, regions[region])
    runs = {case: [] for case in cases}
    for _ in range(REPEATS):
        for case in cases:
            runs[case].append(settle(voxel, case[0], regions[case[1]]))
    return cases, runs


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--voxel", type=float, default=0.005)
    args = p.parse_args(argv)
    logs.configure("WARNING")
    cases, runs = timed_runs(REGIONS, settle, args.voxel, 0.03)
    lines = [
        f"# What a [[swelling]] costs a settled state: the bundled brain, {args.voxel * 1e3:g} mm voxels",
        "",
        f"`.venv/bin/python benchmarks/swelling.py --voxel {args.voxel:g}`; "
        f"{platform.processor() or platform.machine()}, "
        f"one rank; the settled state after the drain (follower CSF load); medians of {REPEATS} runs taken in turn. "
        f"Linear solves: the step solver's (a shrinking or swelling neo-Hookean body's Newton starts from the "
        f"linear answer, a CG solve on the factor of K it already has, not counted).",
        "",
        "| model | swelling | setup (s) | settled state (s) | against none | linear solves | frontal pole (mm) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for model, region in cases:
        setup, solve, solves, pole = (statistics.median(v) for v in zip(*runs[(model, region)]))
        base = statistics.median(r[1] for r in runs[(model, "none")])
        lines.append(
            f"| {model} | {region} | {setup:.2f} | {solve:.2f} | {solve / base:.2f}x | {solves:.0f} | {pole:.2f} |"
        )
        print(lines[-1], flush=True)
    out = ROOT / "benchmarks" / "results" / "swelling.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
