# ---
# jupyter:
#   jupytext:
#     formats: py:light
# ---

# # The skull holds the brain: brain shift with frictionless contact
#
# The bundled brain (supine, CSF drained through a frontal craniotomy) is held in the paper's
# way, by pinning the occipital pole, or by what holds a real brain: the skull, here made from
# the brain's own surface dilated by the CSF layer (`[skull] gap = 0.003`, 3 mm), with the
# brain stem as the only support. Without the skull, the brain stem alone lets the brain swing
# far; with it, the brain settles on the skull's back. Settled state after the drain, linear
# material.
#
# Writes out_skull/comparison.{csv,md,png} and one run folder per case.
#
#     python demos/skull.py                  # 5 mm voxels, about half a minute
#     mpirun -n 2 python demos/skull.py      # the same on two ranks

# +
import argparse
import sys
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_brainshift import InputError, SolverError, load_scene, logs, run

BRAIN_STEM = "z < -0.045 and abs(x) < 0.015"
GAP = 0.003  # m, the CSF layer
CASES = [  # (label, overrides)
    ("occipital pin, no skull", []),
    ("occipital pin, skull", [f"skull.gap={GAP}"]),
    ("brain stem only, no skull", [f"fixed.0.where={BRAIN_STEM}"]),
    ("brain stem only, skull", [f"fixed.0.where={BRAIN_STEM}", f"skull.gap={GAP}"]),
]
# -


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description="The bundled brain with and without a skull.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--voxel", type=float, default=0.005, help="voxel size (m)")
    p.add_argument("--out", default="out_skull", help="output folder")
    return p.parse_args(argv)


# ## Run every case


# +
def run_case(label: str, overrides: list[str], voxel: float, out: Path, comm) -> dict:
    scene = load_scene(
        "brain",
        [
            "time.mode=quasi-static",
            f"mesh.voxel={voxel}",
            "output.pictures=false",
            'output.fields=["displacement"]',
            *overrides,
        ],
    )
    folder = out / label.replace(", ", "_").replace(" ", "_")
    t0 = time.perf_counter()
    try:
        s = run(scene, folder, comm).summary
    except SolverError as exc:  # the last good state is written; say why it stopped
        return {"case": label, "status": str(exc).split(" (stopped")[0], "seconds": time.perf_counter() - t0}
    contact = s.get("skull_contact", {})
    return {
        "case": label,
        "status": "ok",
        "seconds": time.perf_counter() - t0,
        "frontal_pole_mm": float(np.linalg.norm(s["probes"]["frontal_pole"]) * 1e3),
        "max_mm": s["max_displacement_m"] * 1e3,
        "strain": s["validity"]["max_green_lagrange_strain"],
        "pressed_nodes": contact.get("pressed_nodes", ""),
        "skull_force_N": float(np.linalg.norm(contact["force_N"])) if contact else "",
        "penetration_um": contact["max_penetration_m"] * 1e6 if contact else "",
    }


def main(argv=None) -> int:
    args = parse_args(argv)
    logs.configure("WARNING")
    comm = MPI.COMM_WORLD
    out = Path(args.out)
    try:
        rows = [run_case(label, overrides, args.voxel, out, comm) for label, overrides in CASES]
    except InputError as exc:
        if comm.rank == 0:
            print(f"skull.py: error: {exc}", file=sys.stderr)
        return 2
    if comm.rank == 0:
        write_table(out, rows, args.voxel, comm.size)
        plot(out, rows)
        print((out / "comparison.md").read_text())
    comm.barrier()
    return 0


# -


def write_table(out: Path, rows: list[dict], voxel: float, ranks: int) -> None:
    import csv

    keys = [
        "case",
        "status",
        "frontal_pole_mm",
        "max_mm",
        "strain",
        "pressed_nodes",
        "skull_force_N",
        "penetration_um",
        "seconds",
    ]
    with open(out / "comparison.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    lines = [
        f"# The bundled brain with and without a skull ({GAP * 1e3:g} mm CSF layer), {voxel * 1e3:g} mm voxels, "
        f"settled state after the drain, {ranks} rank(s): `python demos/skull.py --voxel {voxel:g}`\n",
        "| case | frontal pole (mm) | largest shift (mm) | largest strain | pressed nodes | skull force (N) | "
        "penetration (um) | run (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"| {r['case']} | – | – | – | – | – | – | {r['seconds']:.1f} | stopped: {r['status']} |")
            continue
        force = f"{r['skull_force_N']:.3f}" if r["skull_force_N"] != "" else ""
        pen = f"{r['penetration_um']:.1f}" if r["penetration_um"] != "" else ""
        lines.append(
            f"| {r['case']} | {r['frontal_pole_mm']:.2f} | {r['max_mm']:.2f} | {r['strain']:.1%} | "
            f"{r['pressed_nodes']} | {force} | {pen} | {r['seconds']:.1f} |"
        )
    (out / "comparison.md").write_text("\n".join(lines) + "\n")


def plot(out: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4))
    x = np.arange(len(rows))
    for k, (key, label) in enumerate((("frontal_pole_mm", "frontal pole"), ("max_mm", "largest shift"))):
        values = [r.get(key, np.nan) for r in rows]
        bars = ax.bar(x + (k - 0.5) * 0.38, np.nan_to_num(values), 0.38, label=label)
        for bar, v in zip(bars, values):
            ax.annotate(
                "stopped" if np.isnan(v) else f"{v:.1f}",
                (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                ha="center",
                va="bottom",
                fontsize=8,
            )
    ax.set_xticks(x, [r["case"].replace(", ", ",\n") for r in rows])
    ax.set_ylabel("shift after the drain (mm)")
    ax.set_title(f"Bundled brain, CSF drained: held by a pin or by the skull ({GAP * 1e3:g} mm CSF layer)")
    ax.legend()
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "comparison.png", dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
