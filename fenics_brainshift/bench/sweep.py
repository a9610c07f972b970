"""Run time against error: `brainshift bench` and benchmarks/time_vs_error.py.

Every configuration computes the same thing — the final shift of a scene — and is timed from
scene to answer (mesh, forms, factor or preconditioner, solves). Its error is measured
against a fine P2 reference of the same scene at fixed sample points (a lattice in the cube;
the fine brain surface's vertices for the brain) and at the probes, as max and RMS of the
displacement difference in mm. One run holds the baseline configurations too, so every
speed-up is a ratio measured in the same process on the same machine:

- "paper-equivalent": P1, the paper's mesh, dynamic Newmark at the paper's dt, plain CG
  (CG + Jacobi), the paper's nodal load rule, run until the shift has settled;
- "naive loop": the same dynamics with the effective matrix assembled and its solver built
  every step, and the load by plain UFL quadrature.

The sweep is serial (one rank): it compares configurations, not parallel efficiency.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI

from ..errors import InputError
from ..logs import get_logger
from ..outputs.points import PointEvaluator
from ..runner import Simulation, build
from ..runner.loop import static_times
from ..scene import Scene, load_scene
from ..stepping import DynamicStepper
from .configs import BENCHES, Config
from .report import read_rows, write

if TYPE_CHECKING:
    from collections.abc import Callable

log = get_logger("bench")


@dataclass
class Result:
    config: Config
    nodes: int
    dofs: int
    setup_s: float
    solve_s: float
    solves: int
    steps: int
    samples: np.ndarray = field(repr=False)
    probes: np.ndarray = field(repr=False)

    @property
    def total_s(self) -> float:
        return self.setup_s + self.solve_s


class NaiveStepper(DynamicStepper):
    """The loop a first version would write: effective matrix and solver rebuilt every step."""

    def step(self) -> int:
        self.A.destroy()
        cm, ck = self.integrator.effective_coefficients(self.damping_a, self.damping_b)
        self.A = self.model.assemble(self.model.combined(cm, ck), with_bcs=True)
        self.solves.reset(self.A)
        return super().step()


def run_config(scene_file: Path, base: list[str], config: Config, samples: np.ndarray) -> Result:
    scene: Scene = load_scene(scene_file, base + config.overrides)
    t0 = time.perf_counter()
    sim = Simulation(scene, MPI.COMM_SELF)
    if config.naive:
        sim.dynamic = NaiveStepper(
            sim.model, sim.state, build.integrator(scene), (scene.damping.a, scene.damping.b), sim.solves
        )
        sim.dynamic.setup()
    sim.setup()
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    steps = 0
    if sim.is_dynamic:
        for _ in range(scene.time.steps):
            sim.step()
            steps += 1
    else:
        sim.solve_to_settled(static_times(scene)[-1])  # the final state only
        steps = 1
    solve = time.perf_counter() - t0
    values = PointEvaluator(sim.model.mesh, samples).values(sim.u)
    probes = sim.probe_values()
    sizes = sim.model.sizes()
    count = sim.solves.count
    sim.destroy()
    return Result(config, sizes["nodes"], sizes["dofs"], setup, solve, count, steps, values, probes)


LEVELS = ("smoke", "quick", "full")


def run_sweep(
    bench: str, level: str, out: Path, progress: Callable | None = None, only: list[str] | None = None
) -> list[dict]:
    """level: "smoke" (seconds: that it all runs), "quick" (coarse meshes), "full".
    only: run just these configurations (and the reference) and merge their rows into the
    table already in out, so a row can be added without re-running the slow baselines."""
    scene_file, base, samples, reference, configs = BENCHES[bench](level)
    previous = {}
    if only:
        known = {c.name for c in configs}
        unknown = [name for name in only if name not in known]
        if unknown:
            raise InputError(
                f"--only: no configuration named {', '.join(map(repr, unknown))} in the {level} "
                f"{bench} sweep; the names are: {', '.join(sorted(known))}"
            )
        previous = {r["config"]: r for r in read_rows(out / f"time_vs_error_{bench}.csv")}
        configs = [c for c in configs if c.name in only or c.name in previous]
    # warm the form compiler's cache on a tiny mesh, so no row pays for compiling its forms
    tiny = {"cube": ["mesh.cells=[2, 2, 1]"], "brain": ["mesh.voxel=0.03"]}[bench]
    for cfg in (reference, *[c for c in configs if c.name not in previous or c.name in (only or ())]):
        warm = Config(cfg.name, cfg.overrides + tiny + ["time.end=0.2", "time.dt=0.2"], cfg.family, cfg.naive)
        run_config(scene_file, base, warm, samples[:1])
    log.info(
        "bench %s: reference %s, %d configurations, %d sample points", bench, reference.name, len(configs), len(samples)
    )
    ref = run_config(scene_file, base, reference, samples)
    rows = []
    items = configs if progress is None else progress(configs, desc=f"bench {bench}")
    for cfg in items:
        if cfg.name in previous and cfg.name not in only:
            rows.append(previous[cfg.name])  # measured in an earlier run, kept as it was
            continue
        r = run_config(scene_file, base, cfg, samples)
        err = np.linalg.norm(r.samples - ref.samples, axis=1) * 1e3
        probe_err = np.linalg.norm(r.probes - ref.probes, axis=1) * 1e3
        rows.append(
            {
                "config": cfg.name,
                "family": cfg.family,
                "nodes": r.nodes,
                "dofs": r.dofs,
                "steps": r.steps,
                "solves": r.solves,
                "setup_s": r.setup_s,
                "solve_s": r.solve_s,
                "total_s": r.total_s,
                "max_error_mm": float(err.max()),
                "rms_error_mm": float(np.sqrt(np.mean(err**2))),
                "probe_error_mm": float(probe_err.max()),
                "max_shift_mm": float(np.linalg.norm(r.samples, axis=1).max() * 1e3),
            }
        )
        log.info(
            "  %-32s %7.2f s  max error %.3f mm  rms %.3f mm",
            cfg.name,
            r.total_s,
            rows[-1]["max_error_mm"],
            rows[-1]["rms_error_mm"],
        )
        write(rows, ref, bench, level, out, only)  # after every row: a sweep cut short keeps what it measured
    write(rows, ref, bench, level, out, only)
    return rows
