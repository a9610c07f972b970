# ---
# jupyter:
#   jupytext:
#     formats: py:light
# ---

# # Brain shift after a frontal craniotomy (Kato et al., section IV)
#
# The bundled MNI ICBM152 2009a brain is voxel-meshed at 5 mm (the paper's embedding method),
# the patient lies supine, and the CSF drains from covering the brain to the craniotomy rim.
# Dynamic FEM with the paper's Table II parameters; the fine brain surface follows the coarse
# model and is written deformed (VTK and STL) for a navigation system or 3D Slicer. Scene:
# `brain.toml` among the bundled scenes (`brainshift scenes`).
#
#     python demos/brain.py                  # serial, writes out_brain/
#     mpirun -n 2 python demos/brain.py      # the same on two ranks
#     python demos/brain.py --shrink 2       # and the whole brain shrinks by 2 % (mannitol)
#     python demos/brain.py --septa          # with the falx and the tentorium, which it slides along

# +
import argparse
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_brainshift import InputError, load_scene, logs, run
from fenics_brainshift.data import scene_path
from fenics_brainshift.scene import Swelling

PAPER_SHIFT_MM = "about 16-17 mm at the most anterior point (paper Table III)"
# -


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description="Brain shift of the bundled MNI brain, supine, frontal craniotomy.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--scene", default=str(scene_path("brain")), help="scene file")
    p.add_argument("--out", default="out_brain", help="output folder")
    p.add_argument("--quasi-static", action="store_true", help="settled states only (no time stepping)")
    p.add_argument(
        "--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="scene overrides, as for brainshift run"
    )
    p.add_argument(
        "--shrink",
        type=float,
        default=0.0,
        metavar="PERCENT",
        help="the whole brain's tissue shrinks by this much (a hyperosmotic drug), over the drain",
    )
    p.add_argument(
        "--septa",
        action="store_true",
        help="turn on the scene's falx and tentorium (rigid membranes the tissue slides along)",
    )
    return p.parse_args(argv)


# ## Run, then report the shift and plot the frontal pole against time (paper Fig. 16)


# +
def main(argv=None) -> int:
    args = parse_args(argv)
    logs.configure("INFO")
    comm = MPI.COMM_WORLD
    overrides = list(args.set) + (["time.mode=quasi-static"] if args.quasi_static else [])
    if args.septa:
        overrides += ["septum.falx.enabled=true", "septum.tentorium.enabled=true"]
    try:
        scene = load_scene(args.scene, overrides)
        if args.shrink:  # as a [[swelling]] table would give it: every cell, over the drain's 10 s
            scene.swelling += (
                Swelling(volume_change=-args.shrink / 100, where="x > -1", schedule=[[0.0, 0.0], [10.0, 1.0]]),
            )
        summary = run(scene, args.out, comm).summary
    except InputError as exc:
        if comm.rank == 0:
            print(f"brain.py: error: {exc}", file=sys.stderr)
        return 2
    if comm.rank == 0:
        out = Path(args.out)
        pole = np.array(summary["probes"]["frontal_pole"]) * 1e3
        print(
            f"brain: {summary['nodes']} nodes, {summary['cells']} tetrahedra, {summary['ranks']} rank(s), "
            f"{summary['steps']} steps, setup {summary['setup_s']:.1f} s, "
            f"median {summary['step_s_median'] * 1e3:.0f} ms per step"
        )
        print(
            f"  CSF level {summary['final_level_m'] * 1e3:.0f} mm; frontal pole moves "
            f"[{pole[0]:.2f}, {pole[1]:.2f}, {pole[2]:.2f}] mm, |u| = {np.linalg.norm(pole):.2f} mm "
            f"(largest anywhere {summary['max_displacement_m'] * 1e3:.2f} mm); the paper: {PAPER_SHIFT_MM}"
        )
        for septum in summary.get("septa", []):
            force = np.array(septum["force_N"])
            print(
                f"  {septum['name']}: {septum['nodes']} nodes; it pushes the tissue with "
                f"{np.linalg.norm(force) * 1e3:.0f} mN in all ({septum['normal_force_sum_N'] * 1e3:.0f} mN summed "
                f"over its nodes, from both sides); the tissue slides up to {septum['largest_slide_m'] * 1e3:.2f} mm "
                f"along it and {septum['largest_motion_across_m'] * 1e3:.1g} mm across"
            )
        print(
            f"  results in {out}/: displacement.xdmf and surface_final.vtk (ParaView), surface_final.stl "
            f"(3D Slicer, mm), probes.csv, summary.json, frontal_pole.png"
        )
        plot_probe(out)
    comm.barrier()
    return 0


def plot_probe(out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(out / "probes.csv") as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(out / "probes.csv", delimiter=",", skiprows=1, ndmin=2)
    t, level = data[:, 0], data[:, header.index("level")]
    uy = data[:, header.index("frontal_pole_y")]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(t, uy * 1e3, "o-" if len(t) < 10 else "-", label="frontal pole, u_y (along gravity)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("displacement (mm)")
    ax.grid(True, alpha=0.3)
    ax2 = ax.twinx()
    ax2.plot(t, level * 1e3, "--", color="tab:gray", label="CSF level")
    ax2.set_ylabel("CSF level along up (mm)")
    lines = ax.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
    ax.legend(lines, [ln.get_label() for ln in lines], loc="center right")
    ax.set_title("Brain shift as the CSF drains (cf. paper Fig. 16)")
    fig.tight_layout()
    fig.savefig(out / "frontal_pole.png", dpi=120)
    plt.close(fig)


# -


if __name__ == "__main__":
    sys.exit(main())
