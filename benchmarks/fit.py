"""`brainshift fit` against a plain scipy least-squares loop that re-runs the scene, in one process.

Synthetic truth (demos/fit.py's): the 5 mm brain with the CSF drained to 40 mm, G = 3000 Pa
and the head turned 8 degrees about z; 20 points on the exposed cortex with 0.5 mm noise.
Fitted from the bundled scene: level, G and the turn. Ours: the forward model built once
(one factorisation), every evaluation re-solved in place. Baseline: the same least_squares
call whose residual function builds the scene with the trial values and solves its settled
state from scratch (mesh, assembly, factorisation, solve) each time. Writes
benchmarks/results/fit.{csv,md}.

    python benchmarks/fit.py [--voxel 0.005]
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI
from scipy.optimize import least_squares

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import logs  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.fit import ForwardModel, Target, fit, fit_parameters  # noqa: E402
from fenics_brainshift.fit.calibrate import DIFFERENCE_STEP  # noqa: E402
from fenics_brainshift.fit.synthetic import measurements, true_scene  # noqa: E402
from fenics_brainshift.outputs.points import PointEvaluator  # noqa: E402
from fenics_brainshift.runner import Simulation  # noqa: E402

TRUTH = {"fluid.level": 0.040, "material.G": 3000.0, "gravity.angle_z": 8.0}


def scene_with(voxel: float, values: dict):
    return true_scene([f"mesh.voxel={voxel}"], values)


def synthetic_target(voxel: float) -> Target:
    pre, measured = measurements([f"mesh.voxel={voxel}"], TRUTH, 20, 0.5e-3, 1, MPI.COMM_SELF)
    return Target(measured, pre, [f"P{i + 1}" for i in range(20)])


def baseline(voxel: float, target: Target, params) -> dict:
    """least_squares with the same settings, the scene re-run for every evaluation."""
    names = [p.name for p in params]
    scale = np.array([p.scale for p in params])
    count = {"runs": 0}

    def residuals(x):
        scene = scene_with(voxel, dict(zip(names, x * scale)))
        sim = Simulation(scene, MPI.COMM_SELF)
        sim.setup()
        sim.solve_to_settled(scene.time.end)
        moved = target.pre + PointEvaluator(sim.model.mesh, target.pre).values(sim.u)
        sim.destroy()
        count["runs"] += 1
        return (moved - target.measured).ravel()

    t0 = time.perf_counter()
    result = least_squares(
        residuals,
        np.array([p.prior for p in params]) / scale,
        bounds=(np.array([p.lower for p in params]) / scale, np.array([p.upper for p in params]) / scale),
        loss="soft_l1",
        f_scale=0.5e-3,
        method="trf",
        diff_step=DIFFERENCE_STEP,
    )
    return {
        "seconds": time.perf_counter() - t0,
        "evaluations": count["runs"],
        "factorisations": count["runs"],
        "values": result.x * scale,
    }


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--voxel", type=float, default=0.005)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "fit"))
    args = p.parse_args(argv)
    logs.configure("WARNING")
    target = synthetic_target(args.voxel)
    t0 = time.perf_counter()
    forward = ForwardModel(scene_with(args.voxel, {}), MPI.COMM_SELF)
    setup = time.perf_counter() - t0
    params = fit_parameters(forward.scene, list(TRUTH), forward.heights())
    result = fit(forward, target, params, noise=0.5e-3)
    ours = {
        "seconds": result.seconds,
        "evaluations": result.solves,
        "factorisations": forward.sim.solves.factors,
        "values": result.values,
    }
    forward.destroy()
    plain = baseline(args.voxel, target, params)
    rows = []
    for name, r in (("brainshift fit (one factor, in place)", ours), ("scipy loop re-running the scene", plain)):
        rows.append(
            {
                "method": name,
                "seconds_after_setup": round(r["seconds"], 2),
                "settled_states": r["evaluations"],
                "factorisations": r["factorisations"],
                **{p.name: float(v) for p, v in zip(params, r["values"])},
            }
        )
        print(rows[-1], flush=True)
    out = Path(args.out)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    fitted = result.as_dict()["parameters"]
    lines = [
        "# Fitting level, G and the head turn to 20 intra-operative points\n",
        f"{machine_line()}; one rank; `python benchmarks/fit.py`; the {args.voxel * 1e3:g} mm brain "
        f"({forward.sim.model.sizes()['nodes']} nodes); "
        f"setup of the forward model {setup:.2f} s (not counted below).\n",
        "Truth: level 40 mm, G = 3000 Pa, turn 8 deg; prior (the scene): 30 mm, 2370 Pa, 0 deg; 0.5 mm noise.\n",
        "| method | seconds after setup | settled states | factorisations | level (mm) | G (Pa) | turn (deg) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['method']} | {r['seconds_after_setup']:.2f} | {r['settled_states']} | {r['factorisations']} | "
            f"{r['fluid.level'] * 1e3:.2f} | {r['material.G']:.0f} | {r['gravity.angle_z']:.2f} |"
        )
    lines += [
        "",
        "Fitted (ours) with one standard deviation: "
        + "; ".join(f"{k} {v['fitted']:.4g} +- {v['std']:.2g} {v['unit']}" for k, v in fitted.items())
        + f". Residual RMS {result.as_dict()['prior_residual_rms_mm']:.2f} mm (scene) -> "
        f"{result.as_dict()['residual_rms_mm']:.2f} mm (fitted).\n",
    ]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out}.md and .csv")


if __name__ == "__main__":
    main()
