"""Skull contact against the same scene without it, on the bundled brain, in one process.

Settled state after the drain (quasi-static, follower CSF load, from rest): without contact
by the default fixed point and by Newton (the solver contact uses), with a skull 3 mm out
(`skull.gap`) and the occipital pin, with the skull and the brain-stem support alone, and the
first skull case again handed the multipliers it settled with (what Newton costs with no
multiplier update left); how deep any surface node's straight path from rest goes past the
skull.
Then the drain by time steps (generalized-alpha, rho_inf = 0.5, as contact requires), with
and without the skull: the whole drain's time, the median step of its first STEPS steps
(before the brain reaches the skull) and of its last STEPS (pressed on it). Counts: linear
solves, factorisations, contact multiplier updates, pressed nodes, exact distance queries,
steps by the fixed point and by Newton. Last, what coupling the pressed nodes exactly through
K's factor would cost (one triangular solve against a multi-right-hand-side solve of many
columns). Writes benchmarks/results/contact.{md,csv}, contact_drain.csv, contact_columns.csv.

    python benchmarks/contact.py [--voxels 0.008 0.005]
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

STEPS = 10
DRAIN = 50  # time steps to t = 10 s, the end of the brain scene's drain
DT = 0.2  # the demo's time step
SETTLED = [
    ("no skull, fixed point", [], "both", False),
    ("no skull, Newton", [], "both", True),
    ("skull 3 mm", ["skull.gap=0.003"], "both", False),
    ("skull 3 mm", ["skull.gap=0.003"], "brain stem", False),
]
DYNAMIC = [("no skull", []), ("skull 3 mm", ["skull.gap=0.003"])]
EXACT_MULTIPLIERS = ("given",)  # the skull case again, from rest, given the multipliers it settled with


def _scene(voxel: float, extra: list[str], supports: str, mode: str):
    scene = load_scene("brain", [f"mesh.voxel={voxel}", f"time.mode={mode}"] + extra)
    if supports == "brain stem":
        scene.fixed = scene.fixed[1:]  # the occipital pin off: the skull holds the brain
    return scene


def deepest_along_paths(sim, samples: int = 61) -> float:
    """How far past the skull (m) the straight path from rest of any surface node goes, at
    ``samples`` points along it: a node that passed through a thin wall of the skull shows
    here, not in the penetration at its end."""
    contact = sim.contact
    u = sim.state.u.x.array.reshape(-1, 3)[contact.nodes]
    phi = [contact.skull.phi(contact.X + s * u)[0].min(initial=np.inf) for s in np.linspace(0.0, 1.0, samples)]
    return max(0.0, -min(phi))


def settled(voxel: float, label: str, extra: list[str], supports: str, newton: bool, multipliers=None) -> dict:
    """One settled state from rest; ``multipliers``: the contact's, set before (the final ones
    of an earlier run: what Newton costs when no multiplier update is left to do)."""
    scene = _scene(voxel, extra, supports, "quasi-static")
    t0 = time.perf_counter()
    sim = Simulation(scene, MPI.COMM_SELF)
    if newton:
        sim.static = NewtonStatic(sim.model, sim.state, sim.solves)
    sim.setup()
    if newton:
        sim.static.setup()
    if multipliers is not None:
        sim.contact.multipliers[:] = multipliers
    free_solves = []  # solves of the contact-free answer that shows whether the skull is reached
    free = getattr(sim.static, "free", None)
    if free is not None:
        solve_free = free.solve
        free.solve = lambda t: (solve_free(t), free_solves.append(sim.solves.count))[0]
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    sim.solve_to_settled(10.0)
    solve = time.perf_counter() - t0
    report = sim.contact.report(sim.state.u) if sim.contact is not None else {}
    row = {
        "voxel_mm": voxel * 1e3,
        "case": label,
        "supports": supports,
        "setup_s": round(setup, 3),
        "final_shift_s": round(solve, 3),
        "linear_solves": sim.solves.count,
        "contact_free_solves": free_solves[-1] if free_solves else "",
        "factorisations": sim.solves.factors,
        "multiplier_updates": getattr(sim.static, "contact_rounds", ""),
        "pressed_nodes": report.get("pressed_nodes", ""),
        "distance_queries": report.get("distance_queries", ""),
        "max_penetration_um": round(report["max_penetration_m"] * 1e6, 2) if report else "",
        "path_depth_um": round(deepest_along_paths(sim) * 1e6, 2) if report else "",
        "max_shift_mm": round(sim.state.max_displacement() * 1e3, 3),
        "frontal_pole_mm": round(float(np.linalg.norm(sim.probe_values()[0])) * 1e3, 3),
        "multipliers": sim.contact.multipliers.copy() if sim.contact is not None else None,
    }
    sim.destroy()
    return row


def stepping(voxel: float, label: str, extra: list[str]) -> dict:
    scene = _scene(
        voxel, extra + ["time.scheme=generalized-alpha", "time.rho_inf=0.5", f"time.dt={DT}"], "both", "dynamic"
    )
    sim = Simulation(scene, MPI.COMM_SELF)
    sim.setup()
    times = []
    for _ in range(DRAIN):
        t0 = time.perf_counter()
        sim.step()
        times.append(time.perf_counter() - t0)
    stepper = sim.dynamic
    fixed_point = getattr(stepper, "fixed_point_steps", DRAIN)
    report = sim.contact.report(sim.state.u) if sim.contact is not None else {}
    row = {
        "voxel_mm": voxel * 1e3,
        "case": label,
        "drain_s": round(sum(times), 2),
        "first_steps_ms": round(1e3 * statistics.median(times[:STEPS]), 1),
        "last_steps_ms": round(1e3 * statistics.median(times[-STEPS:]), 1),
        "fixed_point_steps": fixed_point,
        "newton_steps": DRAIN - fixed_point,
        "linear_solves_per_step": round(sim.solves.count / DRAIN, 1),
        "factorisations": sim.solves.factors,
        "multiplier_updates": getattr(stepper, "contact_rounds", ""),
        "pressed_nodes": report.get("pressed_nodes", ""),
        "max_shift_mm": round(sim.state.max_displacement() * 1e3, 3),
    }
    sim.destroy()
    return row


def columns(voxel: float, counts=(30, 100, 300)) -> list[dict]:
    """What coupling pressed nodes exactly through K's factor costs: a dual (Delassus) or
    low-rank method needs K^-1 e for one to three unit vectors e per pressed node. The
    median of 10 single triangular solves against one multi-right-hand-side solve of
    ``count`` columns (the factor of the contact-free settled state's K)."""
    from petsc4py import PETSc

    sim = Simulation(_scene(voxel, [], "both", "quasi-static"), MPI.COMM_SELF)
    sim.setup()
    pc = sim.solves.solver.ksp.getPC()
    factor = pc.getFactorMatrix()
    n = factor.getSize()[0]
    b, x = factor.createVecRight(), factor.createVecRight()
    b.setRandom()
    single = []
    for _ in range(10):
        t0 = time.perf_counter()
        pc.apply(b, x)
        single.append(time.perf_counter() - t0)
    rows, rng = [], np.random.default_rng(0)
    for count in counts:
        E, Z = (PETSc.Mat().createDense((n, count), comm=PETSc.COMM_SELF) for _ in range(2))
        E.setUp()
        Z.setUp()
        E.getDenseArray()[:] = 0.0
        E.getDenseArray()[rng.choice(n, count, replace=False), np.arange(count)] = 1.0
        E.assemble()
        t0 = time.perf_counter()
        factor.matSolve(E, Z)
        seconds = time.perf_counter() - t0
        rows.append(
            {
                "voxel_mm": voxel * 1e3,
                "dofs": n,
                "single_solve_ms": round(1e3 * statistics.median(single), 2),
                "columns": count,
                "columns_s": round(seconds, 3),
                "per_column_ms": round(1e3 * seconds / count, 2),
            }
        )
        E.destroy()
        Z.destroy()
    sim.destroy()
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--voxels", type=float, nargs="+", default=[0.008, 0.005])
    p.add_argument("--repeat", type=int, default=3, help="runs per settled-state case (median reported)")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "contact"))
    args = p.parse_args(argv)
    logs.configure("WARNING")
    rows, steps, cols = [], [], []
    for voxel in args.voxels:
        cols += columns(voxel)
        print(cols[-1], flush=True)
        settled(voxel, *SETTLED[2])  # compile the forms once, outside the timings
        for case in SETTLED + [EXACT_MULTIPLIERS]:
            given = {}
            if case is EXACT_MULTIPLIERS:  # the multipliers the skull case (both supports) settled with
                case, given = SETTLED[2], {"multipliers": rows[-len(SETTLED) + 2]["multipliers"]}
            runs = [settled(voxel, *case, **given) for _ in range(args.repeat)]
            row = {
                **runs[-1],
                "final_shift_s": statistics.median(r["final_shift_s"] for r in runs),
                "setup_s": statistics.median(r["setup_s"] for r in runs),
            }
            if given:
                row["case"] += ", final multipliers given"
            rows.append(row)
            print({k: v for k, v in row.items() if k != "multipliers"}, flush=True)
        for case in DYNAMIC:
            steps.append(stepping(voxel, *case))
            print(steps[-1], flush=True)
    for row in rows:
        row.pop("multipliers")
    out = Path(args.out)
    for table, suffix in ((rows, ""), (steps, "_drain"), (cols, "_columns")):
        with open(out.parent / f"{out.name}{suffix}.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(table[0]))
            writer.writeheader()
            writer.writerows(table)
    lines = [
        "# Skull contact on the bundled brain\n",
        f"{machine_line()}; DOLFINx {DOLFINX_VERSION}; one rank; `python benchmarks/contact.py`; settled "
        f"states: median of {args.repeat} runs.\n",
        "## The settled state after the drain (from rest, follower CSF load)\n",
        "Solves: all linear solves; of them, those of the contact-free answer solved first (it shows whether "
        "the skull is reached; the rest are Newton's iterations with contact). Path depth: the deepest any "
        "surface node's straight path from rest goes past the skull (61 points along it; a node through a thin "
        "wall of the skull would show here, not in the penetration at its end).\n",
        "| voxel (mm) | case | supports | setup (s) | final shift (s) | solves | of them contact-free | "
        "factorisations | multiplier updates | pressed nodes | distance queries | penetration (um) | path depth "
        "(um) | largest shift (mm) | frontal pole (mm) |",
        "|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['voxel_mm']:g} | {r['case']} | {r['supports']} | {r['setup_s']:.2f} | "
            f"{r['final_shift_s']:.2f} | {r['linear_solves']} | {r['contact_free_solves']} | "
            f"{r['factorisations']} | {r['multiplier_updates']} | {r['pressed_nodes']} | "
            f"{r['distance_queries']} | {r['max_penetration_um']} | {r['path_depth_um']} | "
            f"{r['max_shift_mm']:.2f} | {r['frontal_pole_mm']:.2f} |"
        )
    lines += [
        "\n## The drain by time steps (generalized-alpha, rho_inf = 0.5)\n",
        f"{DRAIN} steps of dt = {DT} s to the end of the drain; both supports. Step times: the median of the "
        f"first {STEPS} steps (the brain not yet on the skull) and of the last {STEPS} (pressed on it). Solves "
        f"count triangular solves and Krylov solves alike.\n",
        "| voxel (mm) | case | drain (s) | first steps (ms) | last steps (ms) | steps by fixed point / Newton | "
        "solves per step | factorisations | multiplier updates | pressed nodes | largest shift (mm) |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in steps:
        lines.append(
            f"| {r['voxel_mm']:g} | {r['case']} | {r['drain_s']:.1f} | {r['first_steps_ms']:.1f} | "
            f"{r['last_steps_ms']:.1f} | {r['fixed_point_steps']} / {r['newton_steps']} | "
            f"{r['linear_solves_per_step']:.1f} | {r['factorisations']} | {r['multiplier_updates']} | "
            f"{r['pressed_nodes']} | {r['max_shift_mm']:.2f} |"
        )
    lines += [
        "\n## What coupling the pressed nodes exactly costs\n",
        "A dual (Delassus) or low-rank treatment of the pressed nodes needs K^-1 e for one to three unit "
        "vectors e per pressed node. One triangular solve with K's factor (median of 10) against one "
        "multi-right-hand-side solve of that many columns:\n",
        "| voxel (mm) | dofs | one solve (ms) | columns | all columns (s) | per column (ms) |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in cols:
        lines.append(
            f"| {r['voxel_mm']:g} | {r['dofs']} | {r['single_solve_ms']:.1f} | {r['columns']} | "
            f"{r['columns_s']:.2f} | {r['per_column_ms']:.2f} |"
        )
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out}.md, .csv, _drain.csv and _columns.csv")


if __name__ == "__main__":
    main()
