"""Where a dynamic step of the 5k-node brain spends its time, and what each choice saved.

Builds the bundled brain at 8 mm voxels (5,087 nodes, 15,261 dofs, P1, Newmark dt = 0.2 s,
the demo's draining CSF, no follower loading), then times, interleaved in one process so
that the ratios are fair on a noisy machine (median of N repetitions):

- the pair of triangular solves with the Cholesky factor kept: MUMPS against CHOLMOD;
- the product with the lumped mass: the assembled matrix (full stiffness pattern of zeros)
  against the diagonal-only matrix the model now keeps;
- K u and K w of one state: two MatMult against one MatMatMult on a two-column block;
- the exact facet load at a level that cuts the brain: every wet facet split (the old path)
  against closed forms for whole facets (hydrostatics.wet_integrals);
- whole steps (Simulation.step) with the level falling and held, the naive loop's steps,
  steps with follower loading;
- the quasi-static settled state at 5 mm voxels (19,480 nodes): setup and solve, with and
  without follower loading (single runs, not medians).

    .venv/bin/python benchmarks/step_parts.py [--repeat 200] [--out benchmarks/results]

writes step_parts.csv and step_parts.md.
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
from petsc4py import PETSc

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.bench.sweep import NaiveStepper  # noqa: E402
from fenics_brainshift.data import scene_path  # noqa: E402
from fenics_brainshift.linalg import PairProduct  # noqa: E402
from fenics_brainshift.physics.hydrostatic import _scatter_add  # noqa: E402
from fenics_brainshift.physics.wet_facets import consistent_loads, split_wet  # noqa: E402
from fenics_brainshift.runner import Simulation, build  # noqa: E402
from fenics_brainshift.scene import load_scene  # noqa: E402

OVERRIDES = ["mesh.voxel=0.008", "fluid.follower=false", "output.pictures=false"]


def median_ms(samples: list[float]) -> float:
    return statistics.median(samples) * 1e3


def factor_solver(A: PETSc.Mat, package: str) -> PETSc.KSP:
    ksp = PETSc.KSP().create(MPI.COMM_SELF)
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("cholesky")
    ksp.getPC().setFactorSolverType(package)
    ksp.setUp()
    return ksp


def all_split_load(hydro, level: float) -> np.ndarray:
    """The facet load as it was before the closed forms: every wet facet split and sorted."""
    wet, n, area, depth = hydro._wet_triangles(level)
    split = split_wet(depth)
    vertex, _ = consistent_loads(depth, area, 1, split)
    local = np.zeros((hydro.V.dofmap.index_map.size_local + hydro.V.dofmap.index_map.num_ghosts, 3))
    dofs = np.take_along_axis(hydro.facets.vertex_dofs[wet], split[0], axis=1)
    _scatter_add(local, dofs, -hydro.rho_fluid * hydro.g_magnitude * vertex[:, :, None] * n[:, None, :])
    return local.ravel()


def timed_steps(naive: bool, scene, count: int):
    """A fresh simulation of the scene (naive: the effective matrix and its solver rebuilt
    every step) and the wall time of each of its first count steps."""
    sim = Simulation(scene, MPI.COMM_SELF)
    if naive:
        sim.dynamic = NaiveStepper(
            sim.model, sim.state, build.integrator(scene), (scene.damping.a, scene.damping.b), sim.solves
        )
        sim.dynamic.setup()
    sim.setup()
    seconds = []
    for _ in range(count):
        t0 = time.perf_counter()
        sim.step()
        seconds.append(time.perf_counter() - t0)
    return sim, seconds


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=200)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)

    scene = load_scene(scene_path("brain"), OVERRIDES)
    sim = Simulation(scene, MPI.COMM_SELF)
    model = sim.model
    sim.setup()
    sizes = model.sizes()
    rows = []

    def record(part, variant, samples, note=""):
        rows.append({"part": part, "variant": variant, "median_ms": round(median_ms(samples), 3), "note": note})

    # triangular solves, interleaved
    rhs = sim.dynamic.A.createVecLeft()
    rhs.setRandom()
    x = rhs.duplicate()
    solvers = {p: factor_solver(sim.dynamic.A, p) for p in ("mumps", "cholmod")}
    entries = {p: int(k.getPC().getFactorMatrix().getInfo()["nz_used"]) for p, k in solvers.items()}
    times = {p: [] for p in solvers}
    for _ in range(args.repeat):
        for p, ksp in solvers.items():
            t0 = time.perf_counter()
            ksp.solve(rhs, x)
            times[p].append(time.perf_counter() - t0)
    for p in solvers:
        record("Cholesky solve", p, times[p], f"factor entries {entries[p]:,}")

    # lumped mass product: assembled pattern against the diagonal
    full = model.assemble(model.mass_form(), with_bcs=False)
    diag = sim.dynamic.M
    times = {"assembled (stiffness pattern)": [], "diagonal only": []}
    for _ in range(args.repeat):
        for name, mat in (("assembled (stiffness pattern)", full), ("diagonal only", diag)):
            solvers["cholmod"].solve(rhs, x)  # a step's solve evicts the matrix from cache
            t0 = time.perf_counter()
            mat.mult(rhs, x)
            times[name].append(time.perf_counter() - t0)
    for name, samples in times.items():
        record("lumped-mass product", name, samples)
    pair = PairProduct(sim.dynamic.K)
    y1, y2 = rhs.duplicate(), rhs.duplicate()
    times = {"two MatMult": [], "one MatMatMult (PairProduct)": []}
    for _ in range(args.repeat):
        for name in times:
            solvers["cholmod"].solve(rhs, x)
            t0 = time.perf_counter()
            if name == "two MatMult":
                sim.dynamic.K.mult(rhs, y1)
                sim.dynamic.K.mult(x, y2)
            else:
                pair.multiply(rhs, x, y1, y2)
            times[name].append(time.perf_counter() - t0)
    for name, samples in times.items():
        record("K u and K w (energy guard, next right-hand side)", name, samples)
    pair.destroy()

    # facet load at a level cutting the brain (the demo's final level)
    hydro = model.fluid.hydro
    level = 0.03
    new = hydro.assemble(level).getArray(readonly=True).copy()
    old = all_split_load(hydro, level)
    difference = float(np.abs(new - old).max() / np.abs(old).max())
    times = {"split every wet facet": [], "closed forms for whole facets": []}
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        all_split_load(hydro, level)
        times["split every wet facet"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        hydro.assemble(level)
        times["closed forms for whole facets"].append(time.perf_counter() - t0)
    for name, samples in times.items():
        record("facet load", name, samples, f"{hydro.wet_facets} wet facets; max relative difference {difference:.1e}")
    for ksp in solvers.values():
        ksp.destroy()

    # whole steps on a fresh state: level falling (steps 1-50), then held
    sim, steps = timed_steps(False, scene, scene.time.steps)
    record("dynamic step", f"level falling ({sim.solves.solver.ksp.getPC().getFactorSolverType()})", steps[:50])
    record("dynamic step", "level held", steps[50:])
    # the first 20 of those steps by the naive loop (effective matrix and factor rebuilt every
    # step, UFL quadrature load): the goal is at least 10x
    naive_scene = load_scene(scene_path("brain"), OVERRIDES + ["fluid.rule=quadrature"])
    _, naive_steps = timed_steps(True, naive_scene, 20)
    record(
        "dynamic step",
        "naive loop (rebuilt every step, quadrature load)",
        naive_steps,
        f"{median_ms(naive_steps) / median_ms(steps[:20]):.0f}x the same 20 steps above",
    )
    # with follower loading (the demo's setting)
    follower_scene = load_scene(scene_path("brain"), OVERRIDES[:1] + ["output.pictures=false"])
    follower, follower_steps = timed_steps(False, follower_scene, follower_scene.time.steps)
    record(
        "dynamic step",
        "follower loading (Anderson)",
        follower_steps,
        f"{follower.solves.count / len(follower_steps):.1f} solves per step",
    )

    # the settled state after the drain, quasi-static, at the paper's 5 mm voxels
    for follow in ("false", "true"):
        overrides = [
            "mesh.voxel=0.005",
            "time.mode=quasi-static",
            "fluid.level=0.03",
            f"fluid.follower={follow}",
            "output.pictures=false",
        ]
        t0 = time.perf_counter()
        static = Simulation(load_scene(scene_path("brain"), overrides), MPI.COMM_SELF)
        static.setup()
        setup = time.perf_counter() - t0
        t0 = time.perf_counter()
        static.solve_to_settled(0.0)
        shift = time.perf_counter() - t0
        nodes = static.model.sizes()["nodes"]
        label = "with" if follow == "true" else "without"
        rows.append(
            {
                "part": "quasi-static final shift, 5 mm",
                "variant": f"{label} follower loading",
                "median_ms": round(shift * 1e3, 3),
                "note": f"{nodes:,} nodes; setup (mesh, forms, factor) {setup:.2f} s; {static.solves.count} solves",
            }
        )

    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "step_parts.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    lines = [
        f"# Parts of a dynamic brain step ({sizes['nodes']:,} nodes, {sizes['dofs']:,} dofs, P1, one rank)",
        "",
        f"Machine: {machine_line()}  ",
        "Command: `.venv/bin/python benchmarks/step_parts.py` "
        f"(median of {args.repeat} interleaved repetitions; steps: median over the run; "
        "the quasi-static rows are single runs)",
        "",
        "| part | variant | median (ms) | note |",
        "|---|---|---:|---|",
    ]
    lines += [f"| {r['part']} | {r['variant']} | {r['median_ms']:.3f} | {r['note']} |" for r in rows]
    (args.out / "step_parts.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
