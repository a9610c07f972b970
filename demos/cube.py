# ---
# jupyter:
#   jupytext:
#     formats: py:light
# ---

# # The gelatin cube (Kato et al., section III, Figs. 6 and 7)
#
# A 50 x 50 x 25 mm gelatin block (E = 729.1 Pa, nu = 0.48, 1048 kg/m3) is glued to the
# floor of a container of silicone oil (975 kg/m3). The oil is drained from 175 ml to 10 ml
# in steps of 25 ml; buoyancy falls and the block sags under its own weight. The scene is
# `cube.toml` among the bundled scenes (`brainshift scenes`) (read its note on the container's size).
#
# 1. The paper's simulation: dynamic FEM (Newmark, lumped mass, Rayleigh damping) on the
#    8,788-node grid through the whole drain; the top surface's mean displacement at the
#    end of each hold is Fig. 6.
# 2. Fig. 7: the settled states on the paper's four grids (quasi-static solves at each
#    volume; the dynamic run settles onto the same answer, which this script checks).
#
#     python demos/cube.py                   # serial, writes out_cube/
#     mpirun -n 2 python demos/cube.py       # the same numbers on two ranks

# +
import argparse
import csv
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_brainshift import InputError, load_scene, logs, run
from fenics_brainshift.data import scene_path

PAPER_GRIDS = ["16x16x9", "20x20x10", "25x25x12", "30x30x15"]  # 2,890 ... 15,376 nodes
# -


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description="The paper's gelatin cube: sag as the oil drains (Figs. 6, 7).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--scene", default=str(scene_path("cube")), help="scene file")
    p.add_argument("--out", default="out_cube", help="output folder")
    p.add_argument("--cells", default="25x25x12", help="grid of the dynamic run, NXxNYxNZ hexahedra")
    p.add_argument("--grids", nargs="*", default=PAPER_GRIDS, help="grids of the quasi-static sweep (Fig. 7)")
    p.add_argument(
        "--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="scene overrides, as for brainshift run"
    )
    return p.parse_args(argv)


def cells(text: str) -> list[int]:
    try:
        nx, ny, nz = (int(c) for c in text.lower().split("x"))
    except ValueError:
        raise InputError(f"grid '{text}' must look like 25x25x12") from None
    return [nx, ny, nz]


def settled_states(out: Path, hold_ends: list[float]) -> np.ndarray:
    """Rows (t, level, top mean u_z) of probes.csv at the end of each hold."""
    with open(out / "probes.csv") as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(out / "probes.csv", delimiter=",", skiprows=1, ndmin=2)
    t, level, top = data[:, 0], data[:, header.index("level")], data[:, header.index("top_mean_z")]
    rows = [np.argmin(np.abs(t - te)) for te in hold_ends]
    return np.column_stack([t[rows], level[rows], top[rows]])


# ## Run: the dynamic drain, then the quasi-static sweep over grids


# +
def main(argv=None) -> int:
    args = parse_args(argv)
    logs.configure("INFO")
    comm = MPI.COMM_WORLD
    out = Path(args.out)
    try:
        grid = cells(args.cells)
        scene = load_scene(args.scene, [f"mesh.cells={grid}", *args.set])
        schedule = scene.fluid.volume.points
        hold_ends = [t for (t, v), (_, v_next) in zip(schedule, schedule[1:] + ((None, None),)) if v != v_next]
        volumes_ml = [scene.fluid.volume(t) * 1e6 for t in hold_ends]
        summary = run(scene, out / "dynamic", comm).summary
        dynamic = settled_states(out / "dynamic", hold_ends)

        sweep = {}
        for g in args.grids:
            static_scene = load_scene(
                args.scene,
                [f"mesh.cells={cells(g)}", "time.mode=quasi-static", 'output.fields=["displacement"]', *args.set],
            )
            s = run(static_scene, out / f"static_{g}", comm).summary
            sweep[g] = (s["nodes"], settled_states(out / f"static_{g}", hold_ends))
    except InputError as exc:
        if comm.rank == 0:
            print(f"cube.py: error: {exc}", file=sys.stderr)
        return 2
    if comm.rank == 0:
        write_figures(out, volumes_ml, dynamic, sweep, summary, args.cells)
    comm.barrier()
    return 0


# -


# ## Figures 6 and 7 as CSV and PNG


# +
def write_figures(out: Path, volumes, dynamic, sweep, summary, main_grid: str) -> None:
    top = dynamic[:, 2] * 1e3
    with open(out / "fig6_top_vs_volume.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["oil_ml", "level_mm", "top_mean_uz_mm", "top_mean_uz_rel_first_mm"])
        for v, row, z in zip(volumes, dynamic, top):
            w.writerow([f"{v:.0f}", f"{row[1] * 1e3:.4f}", f"{z:.5f}", f"{z - top[0]:.5f}"])
    with open(out / "fig7_mesh_sizes.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["oil_ml"] + [f"top_mean_uz_mm_{n}_nodes" for n, _ in sweep.values()])
        for i, v in enumerate(volumes):
            w.writerow([f"{v:.0f}"] + [f"{states[i, 2] * 1e3:.5f}" for _, states in sweep.values()])

    print(
        f"gelatin cube, {summary['nodes']} nodes, {summary['ranks']} rank(s), "
        f"{summary['steps']} Newmark steps, median {summary['step_s_median'] * 1e3:.0f} ms per step"
    )
    print("  oil (ml)  level (mm)  top mean u_z (mm)  settled static (mm)")
    static_main = sweep.get(main_grid)
    for i, v in enumerate(volumes):
        static = f"{static_main[1][i, 2] * 1e3:10.4f}" if static_main else "         -"
        print(f"  {v:8.0f}  {dynamic[i, 1] * 1e3:10.2f}  {top[i]:17.4f}  {static}")
    print(f"  results in {out}/ (fig6_top_vs_volume.csv/.png, fig7_mesh_sizes.csv/.png, dynamic/, static_*/)")
    plot(out, volumes, top, sweep)


def plot(out: Path, volumes, top, sweep) -> None:
    series = {"dynamic FEM, settled": top}
    figure(out / "fig6_top_vs_volume.png", volumes, series, "Gelatin cube: sag as the oil drains (cf. paper Fig. 6)")
    series = {f"{nodes} nodes": states[:, 2] * 1e3 for nodes, states in sweep.values()}
    figure(out / "fig7_mesh_sizes.png", volumes, series, "Mesh size (cf. paper Fig. 7)")


def figure(path: Path, volumes, series: dict, title: str) -> None:
    """Top displacement relative to the first volume against oil volume, one line a series."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for label, z in series.items():
        ax.plot(volumes, z - z[0], "o-", label=label)
    ax.set_xlabel("silicone oil volume (ml)")
    ax.set_ylabel("top surface displacement (mm)\nrelative to 175 ml")
    ax.invert_xaxis()
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# -


if __name__ == "__main__":
    sys.exit(main())
