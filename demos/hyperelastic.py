# ---
# jupyter:
#   jupytext:
#     formats: py:light
# ---

# # Large shifts: the linear brain against the neo-Hookean brain
#
# The bundled brain of `brain.py` (supine, CSF drained to the craniotomy rim), solved for its
# settled state with the paper's linear material and with a compressible neo-Hookean one of
# the same small-strain stiffness, in three settings:
#
# - the paper's G = 2370 Pa with the demo's supports (occipital pole and brain stem);
# - a softer brain, G = 500 Pa: the linear model has no follower equilibrium there (the run
#   stops), the neo-Hookean one has;
# - a narrow support, the brain stem alone: strains far past small, which the linear run
#   reports in its summary's `validity` and the neo-Hookean run resolves.
#
# Writes out_hyperelastic/comparison.{csv,md,png} and one run folder per case.
#
#     python demos/hyperelastic.py                 # 5 mm voxels, about a minute
#     mpirun -n 2 python demos/hyperelastic.py     # the same on two ranks

# +
import argparse
import sys
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_brainshift import InputError, SolverError, load_scene, logs, run

NARROW = "z < -0.045 and abs(x) < 0.015"  # the brain stem alone
CASES = [  # (label, overrides)
    ("G = 2370 Pa", []),
    ("G = 500 Pa", ["material.G=500.0"]),
    ("brain stem only", [f"fixed.0.where={NARROW}"]),
]
MODELS = ("linear", "neo-hookean")
# -


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description="Linear against neo-Hookean on the bundled brain.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--voxel", type=float, default=0.005, help="voxel size (m)")
    p.add_argument("--out", default="out_hyperelastic", help="output folder")
    return p.parse_args(argv)


# ## Run every case with both models


# +
def run_case(label: str, overrides: list[str], model: str, voxel: float, out: Path, comm) -> dict:
    scene = load_scene(
        "brain",
        [
            "time.mode=quasi-static",
            f"mesh.voxel={voxel}",
            f"material.model={model}",
            "output.pictures=false",
            'output.fields=["displacement"]',
            *overrides,
        ],
    )
    folder = out / f"{label.replace(' ', '_').replace('=', '').replace('__', '_')}_{model}"
    t0 = time.perf_counter()
    try:
        s = run(scene, folder, comm).summary
    except SolverError as exc:  # the last good state is written; say why it stopped
        return {
            "case": label,
            "model": model,
            "status": str(exc).split(" (stopped")[0],
            "seconds": time.perf_counter() - t0,
        }
    return {
        "case": label,
        "model": model,
        "status": "ok",
        "seconds": time.perf_counter() - t0,
        "frontal_pole_mm": float(np.linalg.norm(s["probes"]["frontal_pole"]) * 1e3),
        "max_mm": s["max_displacement_m"] * 1e3,
        "strain": s["validity"]["max_green_lagrange_strain"],
        "warning": "warning" in s["validity"],
    }


def main(argv=None) -> int:
    args = parse_args(argv)
    logs.configure("WARNING")
    comm = MPI.COMM_WORLD
    out = Path(args.out)
    try:
        rows = [
            run_case(label, overrides, model, args.voxel, out, comm) for label, overrides in CASES for model in MODELS
        ]
    except InputError as exc:
        if comm.rank == 0:
            print(f"hyperelastic.py: error: {exc}", file=sys.stderr)
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

    keys = ["case", "model", "status", "frontal_pole_mm", "max_mm", "strain", "warning", "seconds"]
    with open(out / "comparison.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    lines = [
        f"# Linear against neo-Hookean, bundled brain, {voxel * 1e3:g} mm voxels, settled state after the drain, "
        f"{ranks} rank(s): `python demos/hyperelastic.py --voxel {voxel:g}`\n",
        "| case | model | frontal pole (mm) | largest shift (mm) | largest strain | run (s) | note |",
        "|---|---|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"| {r['case']} | {r['model']} | – | – | – | {r['seconds']:.1f} | stopped: {r['status']} |")
            continue
        note = "past the linear model's limit in bulk (warned)" if r["warning"] else ""
        lines.append(
            f"| {r['case']} | {r['model']} | {r['frontal_pole_mm']:.2f} | {r['max_mm']:.2f} | "
            f"{r['strain']:.1%} | {r['seconds']:.1f} | {note} |"
        )
    (out / "comparison.md").write_text("\n".join(lines) + "\n")


def plot(out: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.arange(len(CASES))
    for k, model in enumerate(MODELS):
        values = [
            next(r.get("max_mm", np.nan) for r in rows if r["case"] == c and r["model"] == model) for c, _ in CASES
        ]
        bars = ax.bar(x + (k - 0.5) * 0.38, np.nan_to_num(values), 0.38, label=model)
        for bar, v in zip(bars, values):
            ax.annotate(
                "no equilibrium" if np.isnan(v) else f"{v:.1f}",
                (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                ha="center",
                va="bottom",
                fontsize=8,
            )
    ax.set_xticks(x, [c for c, _ in CASES])
    ax.set_ylabel("largest shift after the drain (mm)")
    ax.set_title("Bundled brain, CSF drained: linear against neo-Hookean")
    ax.legend()
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "comparison.png", dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
