"""Newton and the hyperelastic brain against the linear model's fixed-point iteration.

On the bundled brain (quasi-static, follower CSF load, the settled state after the drain,
solved from rest), in one process: the linear material with the Anderson-accelerated
fixed-point iteration (the default) and with Newton's method and the load's tangent; the
neo-Hookean material with Newton. Time after setup (setup: mesh, forms, the factor of K),
linear solves, factorisations, Krylov iterations. Then one dynamic step (the median of the
first STEPS steps of the drain): linear without follower loading (the baseline), linear with
it (the fixed point), neo-Hookean with it (Newton); and, on the 8 mm brain, the follower
tolerance against the answer it gives over the whole 16 s demo. Writes
benchmarks/results/hyperelastic.{csv,md}.

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
from fenics_brainshift.scene.loads import STEP_FOLLOWER_TOL  # noqa: E402
from fenics_brainshift.stepping.newton import NewtonStatic  # noqa: E402

CONFIGS = [("linear", "fixed point (Anderson)"), ("linear", "Newton"), ("neo-hookean", "Newton")]
STEP_CONFIGS = [
    ("linear", "fluid.follower=false", "no follower load (baseline)"),
    ("linear", "fluid.follower=true", "follower, fixed point"),
    ("neo-hookean", "fluid.follower=true", "follower, Newton"),
]
STEPS = 15
TOLERANCES = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2)


def dynamic_step(voxel: float, model: str, follower: str) -> dict:
    """The median time of the first STEPS steps of the brain demo, with counts per step."""
    scene = load_scene("brain", [f"mesh.voxel={voxel}", f"material.model={model}", follower])
    sim = Simulation(scene, MPI.COMM_SELF)
    sim.setup()
    solves, factors = sim.solves.count, sim.solves.factors
    times = []
    for _ in range(STEPS):
        t0 = time.perf_counter()
        sim.step()
        times.append(time.perf_counter() - t0)
    row = {
        "step_ms": round(1e3 * statistics.median(times), 2),
        "solves_per_step": (sim.solves.count - solves) / STEPS,
        "factorisations": sim.solves.factors - factors,
        "cuts": getattr(sim.dynamic, "cuts", 0),
    }
    sim.destroy()
    return row


def follower_tolerance_sweep(voxel: float) -> list[dict]:
    """The whole demo (80 steps) without follower loading (the baseline), and at each follower
    tolerance, the runs interleaved a step at a time (a fair ratio on a shared machine): the
    median step time and its ratio to the baseline's, solves, and how far the frontal pole's path
    strays from the tightest tolerance's."""
    tolerances = (None, *TOLERANCES)
    sims = []
    for tol in tolerances:
        follow = ["fluid.follower=false"] if tol is None else [f"fluid.follower_tol={tol}"]
        sims.append(Simulation(load_scene("brain", [f"mesh.voxel={voxel}", *follow]), MPI.COMM_SELF))
        sims[-1].setup()
    times, paths = [[] for _ in sims], [[] for _ in sims]
    end = sims[0].scene.time.end
    while sims[0].state.t < end - 1e-9:
        for sim, seconds, path in zip(sims, times, paths):
            t0 = time.perf_counter()
            sim.step()
            seconds.append(time.perf_counter() - t0)
            path.append(sim.probe_values()[0].copy())
    base, reference = statistics.median(times[0]), np.array(paths[1])
    rows = []
    for tol, sim, seconds, path in zip(tolerances, sims, times, paths):
        path, step = np.array(path), statistics.median(seconds)
        rows.append(
            {
                "follower_tol": "no follower load" if tol is None else tol,
                "step_ms": round(1e3 * step, 2),
                "ratio": round(step / base, 2),
                "solves": sim.solves.count,
                "pole_deviation_um": float("nan") if tol is None else float(np.abs(path - reference).max() * 1e6),
                "pole_final_mm": float(np.linalg.norm(path[-1]) * 1e3),
            }
        )
        sim.destroy()
    return rows


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
    row = {
        "voxel_mm": voxel * 1e3,
        "nodes": sim.model.sizes()["nodes"],
        "model": model,
        "method": method,
        "setup_s": round(setup, 3),
        "final_shift_s": round(solve, 3),
        "linear_solves": sim.solves.count,
        "factorisations": sim.solves.factors,
        "krylov_iterations": sum(sim.solves.iterations),
        "newton_iterations": len(newton) - 1 if newton else "",
        "max_shift_mm": round(sim.state.max_displacement() * 1e3, 3),
        "frontal_pole_mm": round(float(np.linalg.norm(sim.probe_values()[0])) * 1e3, 3),
    }
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
    steps = []
    for voxel in args.voxels:
        base = None
        for model, follower, label in STEP_CONFIGS:
            runs = [dynamic_step(voxel, model, follower) for _ in range(args.repeat)]
            row = {
                "voxel_mm": voxel * 1e3,
                "model": model,
                "load": label,
                **runs[-1],
                "step_ms": statistics.median(r["step_ms"] for r in runs),
            }
            base = base or row["step_ms"]
            row["ratio"] = round(row["step_ms"] / base, 2)
            steps.append(row)
            print(row, flush=True)
    sweep = follower_tolerance_sweep(args.voxels[0])
    for row in sweep:
        print(row, flush=True)
    out = Path(args.out)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    lines = [
        "# Newton, hyperelasticity and the fixed-point iteration on the bundled brain\n",
        f"{machine_line()}; DOLFINx {DOLFINX_VERSION}; one rank; `python benchmarks/hyperelastic.py`; "
        f"median of {args.repeat} runs.\n",
        "## The settled state\n",
        "Quasi-static, follower CSF load, the settled state after the drain (t = 10 s) solved from rest; "
        "setup = mesh, forms, the factor of K.\n",
        "| voxel (mm) | nodes | model | method | setup (s) | final shift (s) | solves | factorisations | "
        "Krylov its | Newton its | largest shift (mm) | frontal pole (mm) |",
        "|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['voxel_mm']:g} | {r['nodes']} | {r['model']} | {r['method']} | {r['setup_s']:.2f} | "
            f"{r['final_shift_s']:.2f} | {r['linear_solves']} | {r['factorisations']} | "
            f"{r['krylov_iterations']} | {r['newton_iterations']} | {r['max_shift_mm']:.2f} | "
            f"{r['frontal_pole_mm']:.2f} |"
        )
    lines += [
        "\n## One dynamic step\n",
        f"The brain demo (Newmark, dt = 0.2 s), the median of its first {STEPS} steps (the drain, when the "
        f"surface moves most); ratio to the linear step without follower loading at the same voxel size; "
        f"follower_tol at its default.\n",
        "| voxel (mm) | model | load | step (ms) | ratio | solves per step | factorisations | steps cut |",
        "|---:|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in steps:
        lines.append(
            f"| {r['voxel_mm']:g} | {r['model']} | {r['load']} | {r['step_ms']:.1f} | {r['ratio']:.1f} | "
            f"{r['solves_per_step']:.1f} | {r['factorisations']} | {r['cuts']} |"
        )
    lines += [
        "\n## The follower tolerance\n",
        f"The linear {args.voxels[0] * 1e3:g} mm brain demo, all 80 steps, without follower loading, then at "
        f"each `[fluid] follower_tol` (unset: {STEP_FOLLOWER_TOL:g} in a time step); step: the median over the "
        f"run, the runs interleaved a step at a time; ratio: to the step without follower loading; "
        f"deviation: the largest distance between the frontal "
        f"pole's path and the one at {TOLERANCES[0]:g}, over every step.\n",
        "| follower_tol | step (ms) | ratio | solves | pole deviation (um) | frontal pole at 16 s (mm) |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in sweep:
        tol, deviation = r["follower_tol"], r["pole_deviation_um"]
        lines.append(
            f"| {tol if isinstance(tol, str) else format(tol, 'g')} | {r['step_ms']:.1f} | {r['ratio']:.2f} | "
            f"{r['solves']} | {'-' if np.isnan(deviation) else format(deviation, '.3f')} | {r['pole_final_mm']:.4f} |"
        )
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    with open(out.parent / (out.name + "_steps.csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(steps[0]))
        writer.writeheader()
        writer.writerows(steps)
    print(f"wrote {out}.md and .csv")


if __name__ == "__main__":
    main()
