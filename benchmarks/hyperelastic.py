"""Newton and the hyperelastic brain against the linear model's fixed-point iteration.

On the bundled brain (quasi-static, follower CSF load, the settled state after the drain,
solved from rest), in one process: the linear material with the Anderson-accelerated
fixed-point iteration (the default) and with Newton's method and the load's tangent; the
neo-Hookean material with Newton. Time after setup (setup: mesh, forms, the factor of K),
linear solves, factorisations, Krylov iterations. Writes benchmarks/results/hyperelastic.{csv,md}.

    python benchmarks/hyperelastic.py [--voxels 0.008 0.005]
"""
from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import load_scene, logs  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.compat import DOLFINX_VERSION  # noqa: E402
from fenics_brainshift.runner import Simulation  # noqa: E402
from fenics_brainshift.stepping.newton import NewtonStatic  # noqa: E402

CONFIGS = [("linear", "fixed point (Anderson)"), ("linear", "Newton"), ("neo-hookean", "Newton")]


def measure(voxel: float, model: str, method: str) -> dict:
    scene = load_scene("brain", ["time.mode=quasi-static", f"mesh.voxel={voxel}", f"material.model={model}"])
    t0 = time.perf_counter()
    sim = Simulation(scene, MPI.COMM_SELF)
    if method == "Newton" and model == "linear":
        sim.static = NewtonStatic(sim.model, sim.state, sim.solves)
        sim.static.setup()  # the factor of K, as for the others
    sim.setup()
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    sim.solve_to_settled(10.0)  # the drained state, from rest
    solve = time.perf_counter() - t0
    newton = getattr(sim.static, "history", None)
    row = {"voxel_mm": voxel * 1e3, "nodes": sim.model.sizes()["nodes"], "model": model, "method": method,
           "setup_s": round(setup, 3), "final_shift_s": round(solve, 3), "linear_solves": sim.solves.count,
           "factorisations": sim.solves.factors, "krylov_iterations": sum(sim.solves.iterations),
           "newton_iterations": len(newton) - 1 if newton else "",
           "max_shift_mm": round(sim.state.max_displacement() * 1e3, 3),
           "frontal_pole_mm": round(float(np.linalg.norm(sim.probe_values()[0])) * 1e3, 3)}
    sim.destroy()
    return row


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--voxels", type=float, nargs="+", default=[0.008, 0.005])
    p.add_argument("--repeat", type=int, default=3, help="runs per configuration (median reported)")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "hyperelastic"))
    args = p.parse_args(argv)
    logs.configure("WARNING")
    rows = []
    for voxel in args.voxels:
        measure(voxel, "neo-hookean", "Newton")  # compile the forms once, outside the timings
        for model, method in CONFIGS:
            runs = [measure(voxel, model, method) for _ in range(args.repeat)]
            row = runs[-1]
            row["final_shift_s"] = statistics.median(r["final_shift_s"] for r in runs)
            row["setup_s"] = statistics.median(r["setup_s"] for r in runs)
            rows.append(row)
            print(row, flush=True)
    out = Path(args.out)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    lines = ["# Newton, hyperelasticity and the fixed-point iteration on the bundled brain\n",
             f"{machine_line()}; DOLFINx {DOLFINX_VERSION}; one rank; `python benchmarks/hyperelastic.py`; "
             f"median of {args.repeat} runs. Quasi-static, follower CSF load, the settled state after the drain "
             f"(t = 10 s) solved from rest; setup = mesh, forms, the factor of K.\n",
             "| voxel (mm) | nodes | model | method | setup (s) | final shift (s) | solves | factorisations | "
             "Krylov its | Newton its | largest shift (mm) | frontal pole (mm) |",
             "|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['voxel_mm']:g} | {r['nodes']} | {r['model']} | {r['method']} | {r['setup_s']:.2f} | "
                     f"{r['final_shift_s']:.2f} | {r['linear_solves']} | {r['factorisations']} | "
                     f"{r['krylov_iterations']} | {r['newton_iterations']} | {r['max_shift_mm']:.2f} | "
                     f"{r['frontal_pole_mm']:.2f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out}.md and .csv")


if __name__ == "__main__":
    main()
