"""Numerical stability under stress: each case's outcome in one table.

The long versions of tests/test_stability.py, test_guards.py, test_hydrostatics.py and
test_resection.py, plus the cases too slow for the suite (the brain under large follower
displacement, 1/2/4 ranks). Results go to benchmarks/results/stability.md and .csv with the
machine and this command:

    .venv/bin/python benchmarks/stability.py            # everything (a few minutes)
    .venv/bin/python benchmarks/stability.py --quick    # shorter sweeps
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from cube_sizes import machine  # noqa: E402

from fenics_brainshift import compat, logs  # noqa: E402
from fenics_brainshift.data import scene_path  # noqa: E402
from fenics_brainshift.errors import SolverError  # noqa: E402
from fenics_brainshift.physics import HydrostaticLoad  # noqa: E402
from fenics_brainshift.runner import (  # noqa: E402
    Simulation,
    build_model,  # noqa: E402
    run,
)
from fenics_brainshift.runner.build import mesh_from_spec as build_mesh  # noqa: E402
from fenics_brainshift.scene import MeshSpec, load_scene, scene_from_dict  # noqa: E402

COMM = MPI.COMM_SELF
ROWS: list[dict] = []


def record(case: str, setting: str, outcome: str, measure: str) -> None:
    ROWS.append({"case": case, "setting": setting, "outcome": outcome, "measure": measure})
    print(f"{case:28s} {setting:34s} {outcome:8s} {measure}", flush=True)


def cube(nu=0.45, degree=1, solver="cholesky", dt=0.01, end=0.1, scheme="newmark", rho_inf=1.0, **extra):
    data = {
        "mesh": {"shape": "box", "size": [0.02, 0.02, 0.02], "cells": [4, 4, 4]},
        "material": {"E": 3000.0, "nu": nu, "density": 1000.0},
        "fixed": [{"where": "z < 1e-9"}],
        "time": {"mode": "dynamic", "dt": dt, "end": end, "scheme": scheme, "rho_inf": rho_inf},
        "solver": {"kind": solver},
        "element": {"degree": degree},
        "probes": {"top": [0.01, 0.01, 0.02]},
    }
    data.update(extra)
    return scene_from_dict(data)


def energy_norm(sim, f) -> float:
    vec = compat.petsc_vec(f)
    K_vec = vec.duplicate()
    sim.dynamic.K.mult(vec, K_vec)
    return float(np.sqrt(max(vec.dot(K_vec), 0.0)))


def static_of(scene, model=None):
    sim = Simulation(scene, COMM, model)
    sim.solve_to_settled(0.0)
    return sim


# ------------------------------------------------------------------ time steps
def time_steps(steps: int) -> None:
    for scheme, rho in (("newmark", 1.0), ("generalized-alpha", 0.5), ("generalized-alpha", 0.0)):
        for dt in (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0):
            scene = cube(dt=dt, end=steps * dt, scheme=scheme, rho_inf=rho)
            model = build_model(scene, COMM)
            sim = Simulation(scene, COMM, model)
            sim.setup()
            u_static = energy_norm(sim, static_of(scene, model).u)
            peak, outcome = 0.0, "ok"
            try:
                for _ in range(steps):
                    sim.step()
                    peak = max(peak, energy_norm(sim, sim.u))
            except SolverError as exc:
                outcome = f"stopped ({exc})"
            t, ek, es, w = np.array(sim.dynamic.energy.history).T
            drift = np.abs(ek + es - w).max() / max((ek + es).max(), 1e-300)
            newmark = scheme == "newmark"
            name = scheme if newmark else f"gen-alpha rho_inf={rho:g}"
            ok = outcome == "ok" and peak <= 2.0 * u_static * (1 + 1e-8) and np.isfinite(peak)
            ok = ok and (drift < 1e-10 if newmark else True)
            balance = "energy balance error" if newmark else "energy dissipated by the scheme"
            record(
                "time step (sudden gravity)",
                f"{name}, dt={dt:g} s, {steps} steps",
                "ok" if ok else "FAIL",
                f"peak |u|_K / static = {peak / u_static:.3f} (bound 2); {balance} {drift:.1e} of E",
            )


def high_mode_damping() -> None:
    """From a random state at dt = 10 s (omega dt >> 1 for every mode) the amplitude falls by
    rho_inf per step: the spectral radius the user asked for. At omega dt -> infinity the
    amplification matrix has the double eigenvalue -rho_inf (a Jordan block), so the amplitude
    goes as (c1 + c2 n) rho_inf^n; the estimate divides out the factor n."""
    rng = np.random.default_rng(1)
    for rho in (1.0, 0.8, 0.5, 0.0):
        scene = cube(dt=10.0, end=100.0, scheme="generalized-alpha", rho_inf=rho)
        sim = Simulation(scene, COMM)
        n = sim.state.n_owned
        sim.u.x.array[:n] = rng.normal(size=n) * 1e-4
        from dolfinx.fem.petsc import set_bc

        set_bc(compat.petsc_vec(sim.u), sim.model.bcs)
        sim.u.x.scatter_forward()
        sim.setup()
        sim.dynamic.check_energy = rho == 1.0  # the guard is for growth; here energy only falls
        sim.model.gravity.vector.set(0.0)
        sim.dynamic._F_old.set(0.0)
        amplitude = []
        for _ in range(30):
            sim.step()
            amplitude.append(np.sqrt(sum(sim.dynamic.energies())))
        n, span = len(amplitude), 10
        jordan = (n - span) / n if rho < 1.0 else 1.0  # rho_inf = 1: two distinct eigenvalues on the unit circle
        ratio = ((amplitude[-1] / amplitude[-1 - span]) * jordan) ** (1 / span) if amplitude[-1 - span] > 0 else 0.0
        ok = abs(ratio - rho) < 0.05
        record(
            "high-mode damping",
            f"gen-alpha rho_inf={rho:g}, dt=10 s",
            "ok" if ok else "FAIL",
            f"amplitude ratio per step {ratio:.3f} (rho_inf {rho:g})",
        )


# ------------------------------------------------------------------ near incompressibility
def poisson_ratios() -> None:
    sag_p2 = {}
    for degree in (2, 1):
        for nu in (0.3, 0.45, 0.49, 0.4925, 0.499, 0.4999):
            static = static_of(cube(nu=nu, degree=degree, time={"mode": "quasi-static"}))
            sag = -static.probes.values(static.u)[0, 2]
            if degree == 2:
                sag_p2[nu] = sag
            its = {}
            for solver in ("cg-gamg", "cg-jacobi"):
                sim = Simulation(cube(nu=nu, degree=degree, solver=solver, dt=0.05, end=0.1), COMM)
                sim.setup()
                try:
                    its[solver] = sim.step()
                except SolverError:
                    its[solver] = "diverged"
            finite = np.isfinite(static.u.x.array).all()
            locking = f"; P1/P2 sag {sag / sag_p2[nu]:.2f}" if degree == 1 else ""
            record(
                "near incompressible",
                f"P{degree}, nu={nu:g}",
                "ok" if finite else "FAIL",
                f"sag {sag * 1e3:.3f} mm{locking}; CG iterations: GAMG {its['cg-gamg']}, Jacobi {its['cg-jacobi']}",
            )


# ------------------------------------------------------------------ long runs
def long_runs(steps: int) -> None:
    data = {
        "mesh": {"shape": "box", "size": [0.02, 0.02, 0.1], "cells": [1, 1, 3]},
        "material": {"E": 5000.0, "nu": 0.3, "density": 1000.0},
        "fixed": [{"where": "z < 1e-9"}],
        "time": {"mode": "dynamic", "dt": 0.01, "end": steps * 0.01},
        "solver": {"kind": "cholesky"},
    }
    scene = scene_from_dict(data)
    model = build_model(scene, COMM)
    static = static_of(scene, model)
    sim = Simulation(scene, COMM, model)
    sim.u.x.array[:] = static.u.x.array
    sim.setup()
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step()
    drift = np.abs(sim.u.x.array - static.u.x.array).max() / np.abs(static.u.x.array).max()
    record(
        "long run, body at rest",
        f"{steps} undamped Newmark steps",
        "ok" if drift < 1e-9 else "FAIL",
        f"drift |u - u_static| / |u_static| = {drift:.1e} ({time.perf_counter() - t0:.1f} s)",
    )
    sim = Simulation(scene, COMM, model)
    sim.setup()
    for _ in range(steps):
        sim.step()
    t, ek, es, w = np.array(sim.dynamic.energy.history).T
    balance = np.abs(ek + es - w).max() / (ek + es).max()
    record(
        "long run, free vibration",
        f"{steps} undamped steps after sudden gravity",
        "ok" if balance < 1e-8 else "FAIL",
        f"max |E - W| / max E = {balance:.1e}; E stays in [{(ek + es).min():.2e}, {(ek + es).max():.2e}] J",
    )


# ------------------------------------------------------------------ hydrostatics
def volume_below(x, geo, up, level) -> float:
    """Independent of the surface code: each tetrahedron clipped by the plane, volume by the
    convex hull of its vertices below and the edge crossings."""
    from scipy.spatial import ConvexHull, QhullError

    total = 0.0
    for cell in geo:
        p = x[cell]
        h = p @ up - level
        below = [q for q, hh in zip(p, h) if hh <= 0]
        for i in range(4):
            for j in range(i + 1, 4):
                if (h[i] < 0 < h[j]) or (h[j] < 0 < h[i]):
                    below.append(p[i] + h[i] / (h[i] - h[j]) * (p[j] - p[i]))
        if len(below) >= 4:
            try:
                total += ConvexHull(np.array(below)).volume
            except QhullError:
                pass
    return total


def hydrostatics_cases() -> None:
    """Archimedes on awkward geometry: the level through vertices and along edges, slivers,
    dry and fully submerged, as the worst relative error of the resultant."""
    G, RHO = 9.81, 1000.0
    shapes = {
        "box 3x2x2": MeshSpec(shape="box", size=(0.03, 0.02, 0.01), cells=(3, 2, 2)),
        "plate 1e-4 thick (slivers)": MeshSpec(shape="box", size=(0.03, 0.02, 1e-4), cells=(3, 2, 1)),
        "plate 1e-6 thick (slivers)": MeshSpec(shape="box", size=(0.03, 0.02, 1e-6), cells=(3, 2, 1)),
        "ellipsoid h=8 mm": MeshSpec(shape="ellipsoid", size=(0.03, 0.02, 0.015), h=0.008),
    }
    for name, spec in shapes.items():
        mesh = build_mesh(spec, COMM)
        V = compat.vector_space(mesh, 1)
        x = mesh.geometry.x
        geo = compat.geometry_dofmap(mesh)
        volume = float(np.sum(np.abs(np.linalg.det(x[geo[:, 1:]] - x[geo[:, :1]]))) / 6.0)
        worst = 0.0
        for direction in (np.array([0, 0, -1.0]), np.array([1.0, 0, 0]), np.array([0.3, -0.5, -0.8])):
            direction = direction / np.linalg.norm(direction)
            up = -direction
            heights = x @ up
            load = HydrostaticLoad(V, RHO, G * direction, "consistent")
            for level in (
                heights.min() - 0.01,
                heights.max() + 0.01,
                float(np.sort(heights)[len(heights) // 2]),
                float(np.sort(heights)[len(heights) // 3]),
            ):
                load.assemble(level)
                expected = RHO * G * volume_below(x, geo, up, level) * up
                worst = max(worst, np.abs(load.force - expected).max() / (RHO * G * volume))
        record(
            "water line",
            f"{name}: dry/submerged/through vertices",
            "ok" if worst < 1e-6 else "FAIL",
            f"worst relative error of the resultant {worst:.1e} (3 gravity directions)",
        )


# ------------------------------------------------------------------ follower, large shift
def follower_brain(voxel: float) -> None:
    """The brain, softened until the follower load moves it by centimetres: the CSF drains
    from covering the brain to nothing. Linear elasticity has no initial-stress stiffness to
    balance the pressure's load stiffness, so below some G the fixed point of a fully
    submerged soft brain does not exist; the run must then stop with a clear message."""
    for G in (1200.0, 500.0):
        overrides = [
            f"mesh.voxel={voxel}",
            "time.mode=quasi-static",
            f"material.G={G}",
            "fluid.level=[[0.0, 0.085], [1.0, 0.0]]",
        ]
        scene = load_scene(scene_path("brain"), overrides)
        scene.mesh.surface = None
        with tempfile.TemporaryDirectory() as tmp:
            try:
                summary = run(scene, Path(tmp) / "out", COMM).summary
                outcome = "ok" if summary["status"] == "ok" else "FAIL"
                measure = (
                    f"max |u| {summary['max_displacement_m'] * 1e3:.1f} mm, frontal pole "
                    f"{np.linalg.norm(summary['probes']['frontal_pole']) * 1e3:.1f} mm; "
                    f"{summary['linear_solves']} solves for 2 levels"
                )
            except SolverError as exc:
                outcome, measure = "limit", str(exc).split(" (stopped")[0]
        record("follower, large shift", f"brain {voxel * 1e3:g} mm, G = {G:g} Pa, CSF 85 -> 0 mm", outcome, measure)


# ------------------------------------------------------------------ ranks
def ranks() -> None:
    env = dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    probes = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in (1, 2, 4):
            out = Path(tmp) / f"r{n}"
            cmd = [
                shutil.which("mpirun"),
                "-n",
                str(n),
                "--oversubscribe",
                sys.executable,
                "-m",
                "fenics_brainshift.cli",
                "--log-level",
                "WARNING",
                "run",
                str(scene_path("cube")),
                "--out",
                str(out),
                "--set",
                "mesh.cells=[12, 12, 6]",
                "--set",
                "time.end=1.0",
            ]
            subprocess.run(cmd, check=True, env=env, cwd=ROOT, capture_output=True)
            summary = json.loads((out / "summary.json").read_text())
            probes[n] = np.array(summary["probes"]["top_centre"])
    diff = max(np.abs(probes[n] - probes[1]).max() for n in (2, 4)) / np.abs(probes[1]).max()
    # each step's follower iteration stops within 1e-6 of |u|; rank counts stop at different iterates
    record(
        "ranks",
        "cube 12x12x6, 1 / 2 / 4 ranks",
        "ok" if diff < 1e-6 else "FAIL",
        f"largest probe difference {diff:.1e} of |u| (follower tolerance 1e-6)",
    )


# ------------------------------------------------------------------ resection
def resection() -> None:
    data = {
        "mesh": {"shape": "box", "size": [0.02, 0.02, 0.06], "cells": [4, 4, 12]},
        "material": {"E": 3000.0, "nu": 0.45, "density": 1000.0},
        "fixed": [{"where": "z < 1e-9"}],
        "fluid": {"density": 1030.0, "level": [[0.0, 0.07], [0.1, 0.02]]},
        "time": {"mode": "dynamic", "dt": 0.005, "end": 0.3},
        "damping": {"a": 5.0},
        "solver": {"kind": "cg-gamg"},
        "remove": [
            {"at": 0.03, "where": "(x - 0.01)**2 + (y - 0.01)**2 + (z - 0.06)**2 < 0.008**2"},
            {"at": 0.05, "where": "x > 0.014 and z > 0.03"},
            {"at": 0.08, "where": "y < 0.006 and z < 0.045"},
            {"at": 0.1, "where": "0.02 < z < 0.025"},
        ],
    }
    with tempfile.TemporaryDirectory() as tmp:
        summary = run(scene_from_dict(data), Path(tmp) / "out", COMM).summary
    record(
        "resection",
        "block, 4 cuts, the last frees the top",
        "ok" if summary["status"] == "ok" else "FAIL",
        f"{summary['removed_fraction']:.0%} removed; max |u| {summary['max_displacement_m'] * 1e3:.1f} mm "
        f"(the freed piece sinks); {summary['steps']} steps",
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="shorter sweeps")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "stability"), help="output path stem")
    args = p.parse_args(argv)
    logs.configure("WARNING")
    t0 = time.perf_counter()
    time_steps(40 if args.quick else 200)
    high_mode_damping()
    poisson_ratios()
    long_runs(2000 if args.quick else 10_000)
    hydrostatics_cases()
    resection()
    follower_brain(0.008 if args.quick else 0.005)
    ranks()
    elapsed = time.perf_counter() - t0
    stem = Path(args.out)
    stem.parent.mkdir(parents=True, exist_ok=True)
    with open(stem.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(ROWS[0]))
        writer.writeheader()
        writer.writerows(ROWS)
    command = "python benchmarks/stability.py" + (" --quick" if args.quick else "")
    lines = [
        "# Stability under stress\n",
        "Outcome: ok (within the stated bound), FAIL, or limit (the run stopped "
        "with its one-line message: a known limit of linear elasticity with follower loads).\n",
        f"Machine: {machine()}; DOLFINx {compat.DOLFINX_VERSION}; `{command}`, {elapsed:.0f} s.\n",
        "| case | setting | outcome | measure |",
        "|---|---|---|---|",
    ]
    lines += [f"| {r['case']} | {r['setting']} | {r['outcome']} | {r['measure']} |" for r in ROWS]
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    failed = [r for r in ROWS if r["outcome"] == "FAIL"]
    print(f"{len(ROWS)} cases, {len(failed)} failed; wrote {stem}.md and .csv")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
