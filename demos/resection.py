# ---
# jupyter:
#   jupytext:
#     formats: py:light
# ---

# # Resection of a frontal lesion after the CSF has drained
#
# The brain of `brain.py` (bundled MNI brain, 5 mm voxels, supine, CSF drained to the
# craniotomy rim over 10 s), and at t = 12 s a sphere of 15 mm radius in the right frontal lobe
# is removed. The tissue over the cavity loses its support and falls into it; the cut faces
# join the surface the CSF acts on. Dynamic FEM keeps the system solvable even if a piece is
# cut free (the mass matrix has full rank): the reason the paper chose it. Scene:
# `resection.toml` among the bundled scenes (`brainshift scenes`); removed cells carry tissue = 0 in the XDMF output
# (ParaView: Threshold on "tissue" >= 0.5 shows what is left).
#
#     python demos/resection.py                  # serial, writes out_resection/
#     mpirun -n 2 python demos/resection.py      # the same on two ranks
#     python demos/resection.py --skull 3        # a rigid skull 3 mm out holds the brain instead
#                                                # of the occipital pin (brain stem kept)
#
# With `--skull` the brain rests on the skull (frictionless contact, docs/physics.md) and the
# time steps use generalized-alpha (rho_inf = 0.5, as contact requires). The cut faces join
# the contact surface, so tissue cut free at the surface lands on the skull; a piece cut free
# deep inside would fall through the tissue below it (no self-contact: docs/limits.md).

# +
import argparse
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_brainshift import InputError, SolverError, load_scene, logs, run
from fenics_brainshift.data import scene_path

# -


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description="Brain shift with a lesion removed after the CSF has drained.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--scene", default=str(scene_path("resection")), help="scene file")
    p.add_argument("--out", default="out_resection", help="output folder")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="scene overrides, as for brainshift run (e.g. mesh.voxel=0.008 for a quick look)",
    )
    p.add_argument(
        "--skull",
        type=float,
        metavar="MM",
        help="a rigid skull this far (mm) outside the brain replaces the occipital pin",
    )
    return p.parse_args(argv)


BRAIN_STEM = "z < -0.045 and abs(x) < 0.015"  # the scene's second support, kept with the skull


def skull_overrides(gap_mm: float | None) -> list[str]:
    """The scene changes for --skull: the skull from the brain's surface, the brain stem as the
    only support, and the scheme contact needs."""
    if gap_mm is None:
        return []
    return [
        f"skull.gap={gap_mm * 1e-3}",
        f'fixed=[{{where = "{BRAIN_STEM}"}}]',
        "time.scheme=generalized-alpha",
        "time.rho_inf=0.5",
    ]


# ## Run, then report the cavity and plot its roof and floor against time


# +
def main(argv=None) -> int:
    args = parse_args(argv)
    logs.configure("INFO")
    comm = MPI.COMM_WORLD
    try:
        scene = load_scene(args.scene, skull_overrides(args.skull) + args.set)
        summary = run(scene, args.out, comm).summary
    except (InputError, SolverError) as exc:
        if comm.rank == 0:
            print(f"resection.py: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, InputError) else 3
    if comm.rank == 0:
        out = Path(args.out)
        removal = summary["removals"][0]
        t, roof, floor = cavity_history(out)
        before = np.searchsorted(t, removal["t"]) - 1
        print(
            f"resection: {summary['nodes']} nodes, {summary['ranks']} rank(s), {summary['steps']} steps, "
            f"median {summary['step_s_median'] * 1e3:.0f} ms per step"
        )
        print(
            f"  t = {removal['t']:.1f} s: removed {removal['cells']} cells "
            f"({summary['removed_fraction']:.1%} of the brain), {removal['region']}"
        )
        print(
            f"  cavity roof moves {roof[before]:.2f} mm -> {roof[-1]:.2f} mm along gravity; floor "
            f"{floor[before]:.2f} -> {floor[-1]:.2f} mm; "
            f"largest displacement {summary['max_displacement_m'] * 1e3:.2f} mm"
        )
        if "skull_contact" in summary:
            contact = summary["skull_contact"]
            print(
                f"  skull: carries {np.linalg.norm(contact['force_N']):.2f} N on {contact['pressed_nodes']} nodes; "
                f"deepest node {contact['max_penetration_m'] * 1e6:.1f} um past it (tolerance "
                f"{contact['tolerance_m'] * 1e6:.0f} um)"
            )
        print(
            f"  results in {out}/: displacement.xdmf (fields displacement, von_mises, tissue), probes.csv, "
            f"summary.json, cavity.png"
        )
        plot_cavity(out, t, roof, floor, removal["t"])
    comm.barrier()
    return 0


def cavity_history(out: Path):
    """Time and the roof / floor probes' displacement along gravity (-y), mm."""
    with open(out / "probes.csv") as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(out / "probes.csv", delimiter=",", skiprows=1, ndmin=2)
    down = lambda name: -data[:, header.index(f"{name}_y")] * 1e3  # noqa: E731  (gravity is -y)
    return data[:, 0], down("cavity_roof"), down("cavity_floor")


def plot_cavity(out: Path, t, roof, floor, t_removal: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(t, roof, label="cavity roof")
    ax.plot(t, floor, label="cavity floor")
    ax.axvline(t_removal, color="tab:gray", ls="--", label="lesion removed")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("displacement along gravity (mm)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title("Tissue around a resected lesion")
    fig.tight_layout()
    fig.savefig(out / "cavity.png", dpi=120)
    plt.close(fig)


# -


if __name__ == "__main__":
    sys.exit(main())
