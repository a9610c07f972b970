"""What the dural septa change: the bundled brain's settled shift after the drain with and
without its falx and tentorium, at the cortex and deep, supine and lying on its left side.

    .venv/bin/python benchmarks/septa_effect.py   # writes benchmarks/results/septa_effect.md
                                                  # and docs/septa_coronal.png

The points: the frontal pole and the vertex (cortex), the medial frontal cortex beside the
falx, the corpus callosum and the thalamus (deep), the occipital lobe above the tentorium and
the cerebellum below it. The picture: a coronal slice (y = -20 mm) of |u| with and without
the septa, lying on the right side (MNI +x), where the falx carries the upper hemisphere.
"""

from __future__ import annotations

import platform
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_brainshift import load_scene, logs
from fenics_brainshift.outputs.points import PointEvaluator
from fenics_brainshift.outputs.probes import Probes
from fenics_brainshift.runner import Simulation

ROOT = Path(__file__).resolve().parents[1]
SEPTA = ["septum.falx.enabled=true", "septum.tentorium.enabled=true"]
POINTS = {  # MNI, m
    "frontal pole (cortex)": (-0.0245, 0.0745, -0.0075),
    "vertex (cortex)": (-0.0145, -0.0385, 0.0855),
    "medial frontal cortex, 5 mm from the falx": (0.005, 0.03, 0.045),
    "corpus callosum (deep)": (0.0, 0.0, 0.022),
    "thalamus (deep)": (0.012, -0.018, 0.006),
    "occipital lobe, above the tentorium": (0.02, -0.085, 0.0),
    "cerebellum, below the tentorium": (0.02, -0.065, -0.035),
}
POSES = {  # gravity, and the drain along its up
    "supine": [],
    "lying on the right side": [
        "gravity.vector=[9.81, 0.0, 0.0]",
        "fluid.level=[[0.0, 0.08], [10.0, 0.02], [16.0, 0.02]]",
    ],
}
SLICE_Y = -0.02


def settled(overrides: list[str]) -> Simulation:
    scene = load_scene("brain", ["time.mode=quasi-static", "output.pictures=false"] + overrides)
    sim = Simulation(scene, MPI.COMM_WORLD)
    sim.setup()
    sim.solve_to_settled(scene.fluid.schedule.times[-1])
    return sim


def slice_values(sim, X: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """|u| (mm) on the coronal slice's grid, NaN outside the brain."""
    points = np.column_stack([X.ravel(), np.full(X.size, SLICE_Y), Z.ravel()])
    evaluator = PointEvaluator(sim.model.mesh, points)
    values = np.linalg.norm(evaluator.values(sim.u), axis=1) * 1e3
    return np.where(evaluator.inside, values, np.nan).reshape(X.shape)


def main() -> int:
    logs.configure("WARNING")
    rows, pictures = [], {}
    X, Z = np.meshgrid(np.linspace(-0.075, 0.075, 121), np.linspace(-0.05, 0.09, 113))
    for pose, gravity in POSES.items():
        shifts = {}
        for with_septa in (False, True):
            sim = settled(gravity + (SEPTA if with_septa else []))
            shifts[with_septa] = Probes(sim.model.mesh, POINTS).values(sim.u) * 1e3
            if pose != "supine":
                pictures[with_septa] = slice_values(sim, X, Z)
            sim.destroy()
        for i, name in enumerate(POINTS):
            a, b = shifts[False][i], shifts[True][i]
            rows.append(
                f"| {pose} | {name} | {np.linalg.norm(a):.2f} | {np.linalg.norm(b):.2f} | {np.linalg.norm(b - a):.2f} |"
            )
    lines = [
        "# What the falx and the tentorium change: the bundled brain's settled shift after the drain",
        "",
        f"`.venv/bin/python benchmarks/septa_effect.py`; {platform.processor() or platform.machine()}, one rank; "
        f"5 mm voxels, linear, follower CSF load; |u| in mm at each point without and with the septa "
        f"(docs/physics.md), and the size of the difference.",
        "",
        "| pose | point | without septa | with falx + tentorium | difference |",
        "|---|---|---:|---:|---:|",
    ]
    lines += rows
    out = ROOT / "benchmarks" / "results" / "septa_effect.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    picture(X, Z, pictures)
    return 0


def picture(X, Z, pictures) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top = np.nanmax([np.nanmax(v) for v in pictures.values()])
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6), sharey=True)
    for ax, (with_septa, values) in zip(axes, sorted(pictures.items())):
        shown = ax.pcolormesh(X * 1e3, Z * 1e3, values, vmin=0.0, vmax=top, cmap="viridis", shading="auto")
        ax.set_title("with falx and tentorium" if with_septa else "without septa")
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm, MNI: patient's left <- -> right)")
        if with_septa:  # the falx's trace in this slice
            ax.plot([0, 0], [30, 90], "w--", lw=1.2, label="falx (x = 0, z > 30 mm)")
            ax.legend(loc="lower right", fontsize=8)
    axes[0].set_ylabel("z (mm, inferior -> superior)")
    fig.colorbar(shown, ax=axes, label="|u| (mm)", shrink=0.85)
    fig.suptitle(f"Coronal slice y = {SLICE_Y * 1e3:g} mm, lying on the right side (gravity towards +x), CSF drained")
    path = ROOT / "docs" / "septa_coronal.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


if __name__ == "__main__":
    sys.exit(main())
