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

import csv
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mpi4py import MPI

from . import compat
from .embedding import PointEvaluator
from .logs import get_logger
from .model import build_model
from .planner import make_plan
from .scene import Scene, load_scene
from .simulation import Simulation, static_times

log = get_logger("bench")
ROOT = Path(__file__).resolve().parent.parent


@dataclass
class Config:
    name: str
    overrides: list[str]
    family: str  # what the row varies, for the table and the plot's colours
    naive: bool = False


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


# ------------------------------------------------------------------ the scenes
def cube_bench(level: str) -> tuple[Path, list[str], np.ndarray, Config, list[Config]]:
    """The gelatin cube at its last oil volume (10 ml): follower loading, the block mostly dry."""
    scene = ROOT / "demos" / "cube.toml"
    base = ["fluid.volume=10e-6", "time.mode=quasi-static", "output.fields=[\"displacement\"]",
            "output.pictures=false"]
    axes = [np.linspace(0, 0.05, 11), np.linspace(0, 0.05, 11), np.linspace(0, 0.025, 6)]
    samples = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    grids = {"smoke": ["[6, 6, 3]"], "quick": ["[16, 16, 9]", "[20, 20, 10]"],
             "full": ["[16, 16, 9]", "[20, 20, 10]", "[25, 25, 12]", "[30, 30, 15]"]}[level]
    ref_grid = {"smoke": "[8, 8, 4]", "quick": "[20, 20, 10]", "full": "[25, 25, 12]"}[level]
    reference = Config("reference P2", [f"mesh.cells={ref_grid}", "element.degree=2"], "reference")
    base_grid = grids[min(len(grids) - 1, 2 if level == "full" else 1)]
    configs = [Config(f"P1 {g}", [f"mesh.cells={g}"], "element size") for g in grids]
    configs += [Config(f"P2 {g}", [f"mesh.cells={g}", "element.degree=2"], "degree")
                for g in grids[: 2 if level == "full" else 1]]
    at = [f"mesh.cells={base_grid}"]
    end = "0.5" if level == "smoke" else "3.0"
    dynamic = ["time.mode=dynamic", f"time.end={end}", "output.interval=100.0"]
    if level != "smoke":
        configs += [Config(f"P1 {base_grid} {k} rtol={r:g}", at + [f"solver.kind={k}", f"solver.rtol={r}"], "solver")
                    for k, r in (("cg-gamg", 1e-6), ("cg-gamg", 1e-10), ("cg-jacobi", 1e-6), ("cg-jacobi", 1e-10))]
        configs += [Config(f"P1 {base_grid} rule {r}", at + [f"fluid.rule={r}"], "load rule")
                    for r in ("paper", "quadrature")]
        configs += [Config(f"P1 {base_grid} dynamic dt={dt}", at + dynamic + [f"time.dt={dt}"], "time step")
                    for dt in ((0.1,) if level == "quick" else (0.05, 0.1, 0.2))]
        # the planner's fluid-load reuse, switched off: what it saves, and that the answer stays
        configs.append(Config(f"P1 {base_grid} dynamic dt=0.05 no load reuse",
                              at + dynamic + ["time.dt=0.05", "fluid.reuse_tol=0"], "skips"))
    paper = at + dynamic + ["time.dt=0.05", "solver.kind=cg-jacobi", "solver.rtol=1e-6", "fluid.rule=paper"]
    configs.append(Config("paper-equivalent", paper, "baseline"))
    configs.append(Config("naive loop", at + dynamic + ["time.dt=0.05", "fluid.rule=quadrature",
                                                         "fluid.follower=false"], "baseline", naive=True))
    return scene, base, samples, reference, configs


def brain_bench(level: str) -> tuple[Path, list[str], np.ndarray, Config, list[Config]]:
    """The bundled brain, supine, after the CSF has drained (the demo's final state)."""
    from .embedding import load_fine_surface

    scene = ROOT / "demos" / "brain.toml"
    base = ["time.mode=quasi-static", "fluid.level=0.03", "output.fields=[\"displacement\"]", "output.pictures=false"]
    samples = load_fine_surface(load_scene(scene).mesh)[0]
    voxels = {"smoke": ["0.012"], "quick": ["0.008", "0.007"],
              "full": ["0.008", "0.007", "0.006", "0.005", "0.003", "0.002"]}[level]
    ref_voxel = {"smoke": "0.01", "quick": "0.007", "full": "0.005"}[level]
    reference = Config("reference P2", [f"mesh.voxel={ref_voxel}", "element.degree=2"], "reference")
    configs = [Config(f"P1 {float(v) * 1e3:g} mm", [f"mesh.voxel={v}"], "element size") for v in voxels]
    configs += [Config(f"P2 {float(v) * 1e3:g} mm", [f"mesh.voxel={v}", "element.degree=2"], "degree")
                for v in voxels[:2 if level == "full" else 1]]
    # the paper's mesh is 5 mm voxels; quick and smoke runs stand in with coarser ones
    at = [f"mesh.voxel={ {'smoke': '0.012', 'quick': '0.008', 'full': '0.005'}[level] }"]
    if level != "smoke":
        configs += [Config(f"P1 {k} rtol=1e-6", at + [f"solver.kind={k}", "solver.rtol=1e-6"], "solver")
                    for k in ("cg-gamg", "cg-jacobi")]
        configs += [Config("P1 rule paper", at + ["fluid.rule=paper"], "load rule")]
    schedule = "[[0.0, 0.085], [10.0, 0.03], [16.0, 0.03]]" if level != "smoke" else "[[0.0, 0.085], [1.0, 0.03]]"
    dynamic = ["time.mode=dynamic", f"fluid.level={schedule}", f"time.end={16.0 if level != 'smoke' else 1.0}",
               "output.interval=100.0"]
    if level == "full":  # what solving the settled state directly (the planner's choice) saves
        configs.append(Config("P1 5 mm dynamic, Cholesky", at + dynamic + ["time.dt=0.2"], "time stepping"))
    paper = at + dynamic + ["time.dt=0.2", "solver.kind=cg-jacobi", "solver.rtol=1e-6", "fluid.rule=paper"]
    configs.append(Config("paper-equivalent", paper, "baseline"))
    configs.append(Config("naive loop", at + dynamic + ["time.dt=0.2", "fluid.rule=quadrature",
                                                         "fluid.follower=false"], "baseline", naive=True))
    return scene, base, samples, reference, configs


BENCHES = {"cube": cube_bench, "brain": brain_bench}


# ------------------------------------------------------------------ running one configuration
class NaiveSimulation(Simulation):
    """The loop a first version would write: effective matrix and solver rebuilt every step."""

    def step(self) -> int:
        self.A.destroy()
        self.solver.destroy()
        m, sc = self.model, self.scene
        cm, ck = self.integrator.effective_coefficients(sc.damping.a, sc.damping.b)
        from .solver import LinearSolver

        self.A = m.assemble(m.combined(cm, ck), with_bcs=True)
        self.solver = LinearSolver(self.A, sc.solver, "", self._nullspace)
        return super().step()


def run_config(scene_file: Path, base: list[str], config: Config, samples: np.ndarray) -> Result:
    comm = MPI.COMM_SELF
    scene: Scene = load_scene(scene_file, base + config.overrides)
    t0 = time.perf_counter()
    model = build_model(scene, comm)
    sim = (NaiveSimulation if config.naive else Simulation)(model)
    dynamic = make_plan(scene, model.mesh).mode == "dynamic"
    sim.setup_dynamic() if dynamic else sim.setup_static()
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    steps = 0
    if dynamic:
        for _ in range(scene.time.steps):
            sim.step()
            steps += 1
    else:
        for t in static_times(scene)[-1:]:  # the final state only
            sim.solve_static(t)
            steps += 1
    solve = time.perf_counter() - t0
    values = PointEvaluator(model.mesh, samples).values(sim.u)
    probes = sim.probes.values(sim.u)
    sizes = model.sizes()
    sim.solver.destroy()
    return Result(config, sizes["nodes"], sizes["dofs"], setup, solve, sim.history.solves, steps, values, probes)


# ------------------------------------------------------------------ the sweep
LEVELS = ("smoke", "quick", "full")


def sweep(bench: str, level: str, out: Path, progress=None, only: list[str] | None = None) -> list[dict]:
    """level: "smoke" (seconds: that it all runs), "quick" (coarse meshes), "full".
    only: run just these configurations (and the reference) and merge their rows into the
    table already in out, so a row can be added without re-running the slow baselines."""
    scene_file, base, samples, reference, configs = BENCHES[bench](level)
    previous = {}
    if only:
        known = {c.name for c in configs}
        unknown = [name for name in only if name not in known]
        if unknown:
            raise ValueError(f"--only: no configuration named {', '.join(map(repr, unknown))} in the {level} "
                             f"{bench} sweep; the names are: {', '.join(sorted(known))}")
        previous = {r["config"]: r for r in read_rows(out / f"time_vs_error_{bench}.csv")}
        configs = [c for c in configs if c.name in only or c.name in previous]
    # warm the form compiler's cache on a tiny mesh, so no row pays for compiling its forms
    tiny = {"cube": ["mesh.cells=[2, 2, 1]"], "brain": ["mesh.voxel=0.03"]}[bench]
    for cfg in (reference, *[c for c in configs if c.name not in previous or c.name in (only or ())]):
        warm = Config(cfg.name, cfg.overrides + tiny + ["time.end=0.2", "time.dt=0.2"], cfg.family, cfg.naive)
        run_config(scene_file, base, warm, samples[:1])
    log.info("bench %s: reference %s, %d configurations, %d sample points", bench, reference.name,
             len(configs), len(samples))
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
        rows.append({
            "config": cfg.name, "family": cfg.family, "nodes": r.nodes, "dofs": r.dofs, "steps": r.steps,
            "solves": r.solves, "setup_s": r.setup_s, "solve_s": r.solve_s, "total_s": r.total_s,
            "max_error_mm": float(err.max()), "rms_error_mm": float(np.sqrt(np.mean(err**2))),
            "probe_error_mm": float(probe_err.max()),
            "max_shift_mm": float(np.linalg.norm(r.samples, axis=1).max() * 1e3),
        })
        log.info("  %-32s %7.2f s  max error %.3f mm  rms %.3f mm", cfg.name, r.total_s,
                 rows[-1]["max_error_mm"], rows[-1]["rms_error_mm"])
        write(rows, ref, bench, level, out, only)  # after every row: a sweep cut short keeps what it measured
    write(rows, ref, bench, level, out, only)
    return rows


def read_rows(path: Path) -> list[dict]:
    """The rows of an earlier sweep's CSV, numbers as numbers (none if there is no file)."""
    if not path.exists():
        return []
    integers = {"nodes", "dofs", "steps", "solves"}
    with open(path, newline="") as f:
        return [{k: (v if k in ("config", "family") else int(v) if k in integers else float(v)) for k, v in row.items()}
                for row in csv.DictReader(f)]


def pareto_front(rows: list[dict]) -> list[int]:
    """Indices of the rows no other row beats in both run time and max error."""
    front = []
    for i, r in enumerate(rows):
        dominated = any(o["total_s"] <= r["total_s"] and o["max_error_mm"] <= r["max_error_mm"]
                        and (o["total_s"] < r["total_s"] or o["max_error_mm"] < r["max_error_mm"])
                        for o in rows)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: rows[i]["total_s"])


def write(rows: list[dict], ref: Result, bench: str, level: str, out: Path, only=None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"time_vs_error_{bench}"
    with open(stem.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    front = set(pareto_front(rows))
    by_name = {r["config"]: r for r in rows}
    paper, naive = by_name.get("paper-equivalent"), by_name.get("naive loop")
    command = f"brainshift bench --scene {bench}" + ("" if level == "full" else f" --{level}")
    lines = [f"# Run time against error: {bench}\n",
             f"{machine_line()}, DOLFINx {compat.DOLFINX_VERSION}; `{command}`. Serial. Error against {ref.config.name} "
             f"({ref.nodes} nodes, {ref.dofs} dofs) at fixed sample points; time from scene to answer "
             f"(mesh, forms, factor or preconditioner, solves; the form cache warm). * = on the Pareto front.\n",
             "| configuration | varies | nodes | dofs | steps | solves | setup (s) | solve (s) | total (s) | "
             "max error (mm) | RMS error (mm) | probe error (mm) | speed-up on the paper-equivalent |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for i, r in enumerate(rows):
        speed = f"{paper['total_s'] / r['total_s']:.1f}" if paper else ""
        lines.append(f"| {r['config']}{' *' if i in front else ''} | {r['family']} | {r['nodes']} | {r['dofs']} | "
                     f"{r['steps']} | {r['solves']} | {r['setup_s']:.2f} | {r['solve_s']:.2f} | {r['total_s']:.2f} | "
                     f"{r['max_error_mm']:.3f} | {r['rms_error_mm']:.3f} | {r['probe_error_mm']:.3f} | {speed} |")
    if paper and naive:
        lines.append(f"\nThe naive loop takes {naive['total_s']:.1f} s, the paper-equivalent {paper['total_s']:.1f} s "
                     f"(run-time ratio naive / paper-equivalent {naive['total_s'] / paper['total_s']:.2f}); the fastest "
                     f"configuration with at most the paper-equivalent's error: " + _best_line(rows, paper))
    if only:
        lines.append(f"\nRows {', '.join(only)} were (re)measured later with `--only` (and the reference again); "
                     f"the others are from the earlier run, as they were.")
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    plot_pareto(rows, sorted(front, key=lambda i: rows[i]["total_s"]), stem.with_suffix(".png"), bench)


def _best_line(rows: list[dict], paper: dict) -> str:
    ok = [r for r in rows if r["max_error_mm"] <= 1.01 * paper["max_error_mm"]]
    best = min(ok, key=lambda r: r["total_s"])
    return (f"{best['config']}, {best['total_s']:.2f} s ({paper['total_s'] / best['total_s']:.0f}x faster, "
            f"max error {best['max_error_mm']:.3f} mm against {paper['max_error_mm']:.3f} mm).")


def plot_pareto(rows: list[dict], front: list[int], path: Path, bench: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5))
    families = sorted({r["family"] for r in rows})
    for k, fam in enumerate(families):
        sel = [r for r in rows if r["family"] == fam]
        ax.scatter([r["total_s"] for r in sel], [r["max_error_mm"] for r in sel], label=fam, s=36,
                   marker="os^vDP*"[k % 7])
    ax.plot([rows[i]["total_s"] for i in front], [rows[i]["max_error_mm"] for i in front], "k--", lw=1,
            label="Pareto front")
    for r in rows:
        if r["family"] == "baseline":
            ax.annotate(r["config"], (r["total_s"], r["max_error_mm"]), fontsize=8, xytext=(4, 4),
                        textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("run time, scene to answer (s)")
    ax.set_ylabel("max displacement error (mm)")
    ax.set_title(f"{bench}: run time against error (one point per configuration)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def machine_line() -> str:
    import os
    import platform

    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}"
