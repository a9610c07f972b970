# ---
# jupyter:
#   jupytext:
#     formats: py:light
# ---

# # Calibrating to the operating room
#
# A "true" operation: the bundled brain (supine) whose CSF drained further than the scene
# assumes (level 40 mm instead of 30), that is stiffer (G = 3000 Pa instead of 2370) and whose
# head is turned by 8 degrees about the body axis. Once the dura is open, 20 points on the
# exposed (anterior) cortex are measured with 0.5 mm of noise and written as 3D Slicer point
# lists (pre.mrk.json, intra.mrk.json). `brainshift fit` then fits the level, G and the turn
# to them, starting from the bundled scene; 10 more measured points, not used by the fit,
# check the prediction.
#
#     python demos/fit.py                          # 5 mm brain, writes out_demo_fit/
#     python demos/fit.py --set mesh.voxel=0.008   # quicker
#
# out_demo_fit/: pre.mrk.json, intra.mrk.json (the synthetic measurements), fitted.toml, fit.json,
# fit.png (truth, prior and fitted side by side), the fitted scene's run.

# +
import argparse
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_brainshift import InputError, SolverError, load_scene, logs
from fenics_brainshift.cli import main as brainshift
from fenics_brainshift.fit import ForwardModel
from fenics_brainshift.fit.synthetic import measurements
from fenics_brainshift.images import write_markups

TRUTH = {"fluid.level": 0.040, "material.G": 3000.0, "gravity.angle_z": 8.0}
NOISE_MM = 0.5
FITTED, HELD_OUT = 20, 10
# -


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description="Fit the bundled brain scene to synthetic intra-operative points.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", default="out_demo_fit", help="output folder")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="scene overrides")
    p.add_argument("--seed", type=int, default=1, help="of the points' choice and noise")
    return p.parse_args(argv)


# ## The truth, what is measured, the fit


# +
def main(argv=None) -> int:
    args = parse_args(argv)
    logs.configure("WARNING")
    comm = MPI.COMM_WORLD
    out = Path(args.out)
    try:
        pre, intra = measurements(args.set, TRUTH, FITTED + HELD_OUT, NOISE_MM * 1e-3, args.seed, comm)
        labels = [f"P{i + 1}" for i in range(len(pre))]
        if comm.rank == 0:
            out.mkdir(parents=True, exist_ok=True)
            write_markups(out / "pre.mrk.json", labels[:FITTED], pre[:FITTED] * 1e3)
            write_markups(out / "intra.mrk.json", labels[:FITTED], intra[:FITTED] * 1e3)
        comm.barrier()
        sets = [a for s in args.set for a in ("--set", s)]
        code = brainshift(
            [
                "--log-level",
                "WARNING",
                "fit",
                "brain",
                "--target",
                str(out / "intra.mrk.json"),
                "--pre",
                str(out / "pre.mrk.json"),
                "--params",
                ",".join(TRUTH),
                "--noise",
                str(NOISE_MM),
                "--out",
                str(out),
                "--set",
                "time.mode=quasi-static",
                *sets,
            ]
        )
        if code:
            return code
        held = held_out_errors(args.set, out, pre[FITTED:], intra[FITTED:], comm)
    except (InputError, SolverError) as exc:
        if comm.rank == 0:
            print(f"fit.py: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, InputError) else 3
    if comm.rank == 0:
        print(
            f"held-out points ({HELD_OUT}): mean error {held['prior'].mean():.2f} mm with the scene, "
            f"{held['fitted'].mean():.2f} mm fitted (noise {NOISE_MM} mm per axis)"
        )
        picture(out, held)
        print(f"  wrote {out}/fit.png")
    return 0


def held_out_errors(overrides, out, pre, intra, comm) -> dict:
    """|predicted - measured| (mm) at the held-out points, by the scene and by the fitted scene."""
    errors = {}
    for name, scene in (
        ("prior", load_scene("brain", overrides + ["time.mode=quasi-static"])),
        ("fitted", load_scene(out / "fitted.toml", ["time.mode=quasi-static"])),
    ):
        forward = ForwardModel(scene, comm)
        forward.solve({})
        errors[name] = np.linalg.norm(forward.positions(pre) - intra, axis=1) * 1e3
        forward.destroy()
    return errors


def picture(out: Path, held: dict) -> None:
    """Truth, prior and fitted parameter values side by side (fitted with its 2-sigma bar), and
    the held-out errors."""
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fit = json.loads((out / "fit.json").read_text())["parameters"]
    units = {
        "fluid.level": (1e3, "CSF level (mm)"),
        "material.G": (1.0, "G (Pa)"),
        "gravity.angle_z": (1.0, "head turn (deg)"),
    }
    fig, axes = plt.subplots(1, len(units) + 1, figsize=(13, 3.6))
    for ax, (name, (factor, label)) in zip(axes, units.items()):
        p = fit[name]
        ax.bar([0, 1], [TRUTH[name] * factor, p["prior"] * factor], color=["tab:green", "tab:gray"])
        ax.bar([2], [p["fitted"] * factor], yerr=[2 * (p["std"] or 0.0) * factor], color="tab:blue", capsize=6)
        ax.set_xticks([0, 1, 2], ["truth", "scene", "fitted\n(+-2 sd)"])
        ax.set_title(label)
    ax = axes[-1]
    ax.boxplot([held["prior"], held["fitted"]], labels=["scene", "fitted"])
    ax.set_title(f"error at {HELD_OUT} held-out points (mm)")
    fig.suptitle(f"brainshift fit: {FITTED} points on the exposed cortex, {NOISE_MM} mm noise", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "fit.png", dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
