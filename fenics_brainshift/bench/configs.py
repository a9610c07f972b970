"""The configurations a benchmark sweep compares, for the cube and the bundled brain."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data import scene_path
from ..outputs.fine_surface import load_fine_surface
from ..scene import load_scene


@dataclass
class Config:
    name: str
    overrides: list[str]
    family: str  # what the row varies, for the table and the plot's colours
    naive: bool = False


# ------------------------------------------------------------------ the scenes
def cube_bench(level: str) -> tuple[Path, list[str], np.ndarray, Config, list[Config]]:
    """The gelatin cube at its last oil volume (10 ml): follower loading, the block mostly dry."""
    scene = scene_path("cube")
    base = ["fluid.volume=10e-6", "time.mode=quasi-static", 'output.fields=["displacement"]', "output.pictures=false"]
    axes = [np.linspace(0, 0.05, 11), np.linspace(0, 0.05, 11), np.linspace(0, 0.025, 6)]
    samples = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    grids = {
        "smoke": ["[6, 6, 3]"],
        "quick": ["[16, 16, 9]", "[20, 20, 10]"],
        "full": ["[16, 16, 9]", "[20, 20, 10]", "[25, 25, 12]", "[30, 30, 15]"],
    }[level]
    ref_grid = {"smoke": "[8, 8, 4]", "quick": "[20, 20, 10]", "full": "[25, 25, 12]"}[level]
    reference = Config("reference P2", [f"mesh.cells={ref_grid}", "element.degree=2"], "reference")
    base_grid = grids[min(len(grids) - 1, 2 if level == "full" else 1)]
    configs = [Config(f"P1 {g}", [f"mesh.cells={g}"], "element size") for g in grids]
    configs += [
        Config(f"P2 {g}", [f"mesh.cells={g}", "element.degree=2"], "degree")
        for g in grids[: 2 if level == "full" else 1]
    ]
    at = [f"mesh.cells={base_grid}"]
    end = "0.5" if level == "smoke" else "3.0"
    dynamic = ["time.mode=dynamic", f"time.end={end}", "output.interval=100.0"]
    if level != "smoke":
        configs += [
            Config(f"P1 {base_grid} {k} rtol={r:g}", at + [f"solver.kind={k}", f"solver.rtol={r}"], "solver")
            for k, r in (("cg-gamg", 1e-6), ("cg-gamg", 1e-10), ("cg-jacobi", 1e-6), ("cg-jacobi", 1e-10))
        ]
        # the UFL reference rule integrates on the undeformed surface: no follower loading
        configs += [
            Config(f"P1 {base_grid} rule paper", at + ["fluid.rule=paper"], "load rule"),
            Config(
                f"P1 {base_grid} rule quadrature, reference surface",
                at + ["fluid.rule=quadrature", "fluid.follower=false"],
                "load rule",
            ),
        ]
        configs += [
            Config(f"P1 {base_grid} dynamic dt={dt}", at + dynamic + [f"time.dt={dt}"], "time step")
            for dt in ((0.1,) if level == "quick" else (0.05, 0.1, 0.2))
        ]
        # the planner's fluid-load reuse, switched off: what it saves, and that the answer stays
        configs.append(
            Config(
                f"P1 {base_grid} dynamic dt=0.05 no load reuse",
                at + dynamic + ["time.dt=0.05", "fluid.reuse_tol=0"],
                "skips",
            )
        )
    paper = at + dynamic + ["time.dt=0.05", "solver.kind=cg-jacobi", "solver.rtol=1e-6", "fluid.rule=paper"]
    configs.append(Config("paper-equivalent", paper, "baseline"))
    configs.append(
        Config(
            "naive loop",
            at + dynamic + ["time.dt=0.05", "fluid.rule=quadrature", "fluid.follower=false"],
            "baseline",
            naive=True,
        )
    )
    return scene, base, samples, reference, configs


def brain_bench(level: str) -> tuple[Path, list[str], np.ndarray, Config, list[Config]]:
    """The bundled brain, supine, after the CSF has drained (the demo's final state)."""
    scene = scene_path("brain")
    base = ["time.mode=quasi-static", "fluid.level=0.03", 'output.fields=["displacement"]', "output.pictures=false"]
    mesh = load_scene(scene).mesh
    samples = load_fine_surface(mesh.file, mesh.surface, mesh.scale, mesh.labels)[0]
    voxels = {
        "smoke": ["0.012"],
        "quick": ["0.008", "0.007"],
        "full": ["0.008", "0.007", "0.006", "0.005", "0.003", "0.002"],
    }[level]
    ref_voxel = {"smoke": "0.01", "quick": "0.007", "full": "0.005"}[level]
    reference = Config("reference P2", [f"mesh.voxel={ref_voxel}", "element.degree=2"], "reference")
    configs = [Config(f"P1 {float(v) * 1e3:g} mm", [f"mesh.voxel={v}"], "element size") for v in voxels]
    configs += [
        Config(f"P2 {float(v) * 1e3:g} mm", [f"mesh.voxel={v}", "element.degree=2"], "degree")
        for v in voxels[: 2 if level == "full" else 1]
    ]
    # the paper's mesh is 5 mm voxels; quick and smoke runs stand in with coarser ones
    at = [f"mesh.voxel={ {'smoke': '0.012', 'quick': '0.008', 'full': '0.005'}[level] }"]
    if level != "smoke":
        configs += [
            Config(f"P1 {k} rtol=1e-6", at + [f"solver.kind={k}", "solver.rtol=1e-6"], "solver")
            for k in ("cg-gamg", "cg-jacobi")
        ]
        configs += [Config("P1 rule paper", at + ["fluid.rule=paper"], "load rule")]
    schedule = "[[0.0, 0.085], [10.0, 0.03], [16.0, 0.03]]" if level != "smoke" else "[[0.0, 0.085], [1.0, 0.03]]"
    dynamic = [
        "time.mode=dynamic",
        f"fluid.level={schedule}",
        f"time.end={16.0 if level != 'smoke' else 1.0}",
        "output.interval=100.0",
    ]
    if level == "full":  # what solving the settled state directly (the planner's choice) saves
        configs.append(Config("P1 5 mm dynamic, Cholesky", at + dynamic + ["time.dt=0.2"], "time stepping"))
    paper = at + dynamic + ["time.dt=0.2", "solver.kind=cg-jacobi", "solver.rtol=1e-6", "fluid.rule=paper"]
    configs.append(Config("paper-equivalent", paper, "baseline"))
    configs.append(
        Config(
            "naive loop",
            at + dynamic + ["time.dt=0.2", "fluid.rule=quadrature", "fluid.follower=false"],
            "baseline",
            naive=True,
        )
    )
    return scene, base, samples, reference, configs


BENCHES = {"cube": cube_bench, "brain": brain_bench}
