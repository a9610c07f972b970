# ---
# jupyter:
#   jupytext:
#     formats: py:light
# ---

# # Model-updated guidance: the atlas before surgery, the update in theatre
#
# Before surgery `brainshift atlas` computes the bundled brain's settled states over 8 drain
# levels and 25 head poses, with the whole brain's shrinkage as one more mode. The "true"
# operation, made by the full model on its own, is one the atlas does not hold: the CSF
# drained to 35 mm (between the atlas's levels), a brain stiffer than the scene's (G = 3000 Pa
# instead of 2370) and the head turned by 8 degrees about the body axis and -4 about the
# left-right axis (between its poses). Once the dura is open, 20 points on the exposed cortex
# are measured with 0.5 mm of noise; `brainshift update` fits the atlas's weights to them in
# milliseconds. The error of the prediction against the truth, before and after, at every
# node: on the cortex and in a slice through the deep tissue below the craniotomy.
#
#     python demos/update.py                          # 5 mm brain, writes out_update/
#     python demos/update.py --set mesh.voxel=0.01    # quicker
#     python demos/update.py --resection              # after the tumour comes out: out_update_resection/
#
# out_update/: atlas/ (atlas.h5, atlas.json), pre.mrk.json, intra.mrk.json, the update's run
# folder (displacement.xdmf, update.json, ...), update.png (the error before and after).
#
# With --resection the atlas holds the tumour's resection in 3 stages (`--resect`); the truth
# removes half of it (not one of the stages: the cells above its centre) from a neo-Hookean
# brain with the fluid in the cavity, and is measured by 15 landmark pairs within 40 mm of the
# cavity (1 mm noise) and 10 points on its wall (0.5 mm). The error within 10 mm of the wall:
# the prediction, the update of the atlas before the resection (--stage 0: the pairs alone,
# there is no wall to fit the wall's points to) and the update across the stages (pairs and
# wall), as a table and as a sagittal slice through the cavity (cavity.png).

# +
import argparse
import json
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_brainshift import InputError, SolverError, logs
from fenics_brainshift.atlas import store
from fenics_brainshift.cli import main as brainshift
from fenics_brainshift.fit.synthetic import measurements, true_scene
from fenics_brainshift.images import write_markups
from fenics_brainshift.outputs.vertices import GlobalVertices
from fenics_brainshift.runner import Simulation

TRUTH = {"fluid.level": 0.035, "material.G": 3000.0, "gravity.angle_z": 8.0, "gravity.angle_x": -4.0}
TUMOUR = "(x-0.03)**2 + (y-0.045)**2 + (z-0.02)**2 < 0.02**2"  # under the supine brain's top (y up)
RESECTED = {"where": f"{TUMOUR} and y >= 0.045", "fluid.level": 0.052, "gravity.angle_z": 3.0}
RESECTION_VARY = ["fluid.level=0.0:0.06:7", "gravity.angle_z=-6,0,6"]
NOISE_MM = 0.5
POINTS = 20
DEEP_MM = 40.0  # the deep tissue: interior nodes this close to the craniotomy's centre
# -


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description="Build an atlas of the bundled brain and update it to synthetic points.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", default="out_update", help="output folder")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="scene overrides")
    p.add_argument("--seed", type=int, default=1, help="of the points' choice and noise")
    p.add_argument("--resection", action="store_true", help="an atlas with resection stages, a resected truth")
    args = p.parse_args(argv)
    if args.resection and args.out == "out_update":
        args.out = "out_update_resection"
    return args


# ## Before surgery, the truth, what is measured, the update


# +
def main(argv=None) -> int:
    args = parse_args(argv)
    logs.configure("WARNING")
    comm = MPI.COMM_WORLD
    if comm.size > 1:
        print("update.py: one rank (the atlas command itself runs under mpirun)", file=sys.stderr)
        return 2
    out = Path(args.out)
    sets = [a for s in args.set for a in ("--set", s)]
    if args.resection:
        return resection(args, out, sets)
    try:
        code = brainshift(["--log-level", "WARNING", "atlas", "brain", "-o", str(out / "atlas"), *sets])
        if code:
            return code
        pre, intra = measurements(args.set, TRUTH, POINTS, NOISE_MM * 1e-3, args.seed, comm)
        labels = [f"P{i + 1}" for i in range(POINTS)]
        write_markups(out / "pre.mrk.json", labels, pre * 1e3)
        write_markups(out / "intra.mrk.json", labels, intra * 1e3)
        code = brainshift(
            [
                "--log-level",
                "WARNING",
                "update",
                str(out / "atlas"),
                "--pre",
                str(out / "pre.mrk.json"),
                "--target",
                str(out / "intra.mrk.json"),
                "--noise",
                str(NOISE_MM),
                "--out",
                str(out),
                "--replace",
            ]
        )
        if code:
            return code
        truth = true_state(args.set)
    except (InputError, SolverError) as exc:
        print(f"update.py: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, InputError) else 3
    atlas = store.read(out / "atlas")
    from fenics_brainshift.outputs.run_folder import read_last_state

    _, _, updated, _ = read_last_state(out / "displacement.xdmf")
    errors = table(atlas, truth, updated, json.loads((out / "update.json").read_text()))
    picture(out, atlas, errors)
    print(f"  wrote {out}/update.png")
    return 0


def true_state(overrides) -> np.ndarray:
    """The true operation's displacement at the atlas's vertices (the full model, on its own)."""
    scene = true_scene(overrides, TRUTH)
    sim = Simulation(scene, MPI.COMM_WORLD)
    sim.setup()
    sim.solve_to_settled(scene.time.end)
    u = GlobalVertices(sim.model.mesh).values(sim.u)
    sim.destroy()
    return u


# -


# ## The error before and after


# +
def regions(atlas) -> dict:
    points = atlas.points
    boundary = np.zeros(len(points), dtype=bool)
    boundary[atlas.boundary.vertices] = True
    exposed = boundary & (points[:, 1] > 0.03)
    centre = points[exposed].mean(axis=0)
    deep = ~boundary & (np.linalg.norm(points - centre, axis=1) < DEEP_MM * 1e-3)
    return {"exposed cortex": exposed, "deep tissue below it": deep, "every node": np.ones(len(points), bool)}


def table(atlas, truth, updated, report) -> dict:
    errors = {
        "scene": np.linalg.norm(atlas.prior_vertex - truth, axis=1) * 1e3,
        "updated": np.linalg.norm(updated - truth, axis=1) * 1e3,
    }
    print(
        f"update: {report['points']} points, weights in {report['timings_ms']['weights_ms']:.0f} ms, "
        f"the whole update {report['timings_ms']['total_ms']:.0f} ms; G {report['stiffness_G_Pa']:.0f} Pa "
        f"(truth {TRUTH['material.G']:g}); leave-one-out RMS {report['leave_one_out_rms_mm']:.2f} mm"
    )
    print(f"{'mean error (mm)':28s} {'scene':>8s} {'updated':>8s}")
    for name, mask in regions(atlas).items():
        print(f"{name:28s} {errors['scene'][mask].mean():8.2f} {errors['updated'][mask].mean():8.2f}")
    return errors


def picture(out: Path, atlas, errors: dict) -> None:
    """The error on the cortex seen from above (supine: +y up) and in the sagittal slice
    through the craniotomy's centre, before and after the update."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = atlas.points * 1e3
    masks = regions(atlas)
    top = masks["exposed cortex"]
    planes = np.unique(points[:, 0])  # the vertices' x planes: the one nearest the craniotomy's centre
    centre_x = planes[np.argmin(np.abs(planes - points[top, 0].mean()))]
    plane = np.abs(points[:, 0] - centre_x) < 1e-6
    vmax = float(np.ceil(max(errors["scene"][top | plane].max(), 1.0)))
    fig, axes = plt.subplots(2, 2, figsize=(10, 8.5))
    for column, name in enumerate(("scene", "updated")):
        e = errors[name]
        ax = axes[0, column]
        s = ax.scatter(points[top, 0], points[top, 2], c=e[top], cmap="magma_r", vmin=0, vmax=vmax, s=18)
        ax.set_title(f"{name}\nexposed cortex from above: mean {e[top].mean():.2f} mm", fontsize=10)
        ax.set_xlabel("x (R, mm)")
        ax.set_ylabel("z (S, mm)")
        ax.set_aspect("equal")
        ax = axes[1, column]
        ax.scatter(points[plane, 2], points[plane, 1], c=e[plane], cmap="magma_r", vmin=0, vmax=vmax, s=18)
        ax.set_title(f"{name}\nsagittal slice x = {centre_x:.0f} mm: mean {e[plane].mean():.2f} mm", fontsize=10)
        ax.set_xlabel("z (S, mm)")
        ax.set_ylabel("y (A, up, mm)")
        ax.set_aspect("equal")
    bar = fig.colorbar(s, ax=axes, shrink=0.8)
    bar.set_label("error against the truth (mm)")
    fig.suptitle(
        f"brainshift update: {POINTS} cortex points, {NOISE_MM} mm noise; the truth by the full model, "
        f"between the atlas's samples",
        fontsize=10,
    )
    fig.savefig(out / "update.png", dpi=90)
    plt.close(fig)


# -


# ## After the tumour comes out (--resection)


# +
def resection(args, out: Path, sets: list[str]) -> int:
    from fenics_brainshift.fit.synthetic import resected_truth

    quiet = ["--log-level", "WARNING"]
    vary = [a for v in RESECTION_VARY for a in ("--vary", v)]
    try:
        code = brainshift(quiet + ["atlas", "brain", "-o", str(out / "atlas"), *sets, *vary, "--resect", TUMOUR])
        if code:
            return code
        values = {k: v for k, v in RESECTED.items() if k != "where"}
        truth = resected_truth(args.set + ["material.model=neo-hookean"], values, RESECTED["where"])
        pre, intra, wall = resection_points(truth, args.seed)
        labels = [f"L{i + 1}" for i in range(len(pre))]
        write_markups(out / "pre.mrk.json", labels, pre * 1e3)
        write_markups(out / "intra.mrk.json", labels, intra * 1e3)
        write_markups(out / "wall.mrk.json", [f"W{i + 1}" for i in range(len(wall))], wall * 1e3)
        pairs = ["--pre", str(out / "pre.mrk.json"), "--target", str(out / "intra.mrk.json"), "--noise", "1"]
        wall = ["--cavity", str(out / "wall.mrk.json")]  # (before the resection there is no wall to fit them to)
        for folder, options in (("update_stages", wall + ["--stage", "auto"]), ("update_no_stages", ["--stage", "0"])):
            argv = ["update", str(out / "atlas"), *pairs, *options, "--out", str(out / folder), "--overwrite"]
            code = brainshift(quiet + argv)
            if code:
                return code
    except (InputError, SolverError) as exc:
        print(f"update.py: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, InputError) else 3
    from fenics_brainshift.outputs.run_folder import read_last_state

    atlas = store.read(out / "atlas")
    chosen = json.loads((out / "update_stages" / "update.json").read_text())["resection_stage"]
    _, cells, staged, tissue = read_last_state(out / "update_stages" / "displacement.xdmf")
    shifts = {
        "prediction": atlas.prior_vertex,
        "update, no stages": read_last_state(out / "update_no_stages" / "displacement.xdmf")[2],
        "update, stages": staged,
    }
    # (a node the chosen stage removed has no shift of its own there: left out of the comparison)
    kept = np.zeros(len(truth.points), dtype=bool)
    kept[np.unique(cells if tissue is None else cells[tissue > 0.5])] = True
    near = near_wall(truth) & kept
    print(
        f"resection: {truth.removed_ml:.1f} ml removed; stage chosen {chosen['number']} "
        f"({chosen['removed_ml']:.1f} ml); {int(near.sum())} nodes within 10 mm of the wall "
        f"({int((near_wall(truth) & ~kept).sum())} more the stage removed)\n{'mean error there (mm)':44s}"
    )
    errors = {name: np.linalg.norm(u - truth.displacement, axis=1) * 1e3 for name, u in shifts.items()}
    for name, e in errors.items():
        print(f"  {name:42s} {e[near].mean():6.2f}")
    cavity_picture(out, truth, errors, near)
    print(f"  wrote {out}/cavity.png")
    return 0


def resection_points(truth, seed: int):
    """15 landmark pairs within 40 mm of the cavity (1 mm noise) and 10 points on its wall (0.5 mm)."""
    rng = np.random.default_rng(seed)
    points, u = truth.points, truth.displacement
    alive = np.unique(truth.present)
    centre = points[np.unique(truth.removed)].mean(axis=0)
    near = alive[np.linalg.norm(points[alive] - centre, axis=1) < 0.04]
    picked = rng.choice(near, 15, replace=False)
    touched = rng.choice(truth.wall, 10, replace=False)
    intra = points[picked] + u[picked] + rng.normal(0.0, 1e-3, (15, 3))
    return points[picked], intra, points[touched] + u[touched] + rng.normal(0.0, 0.5e-3, (10, 3))


def near_wall(truth) -> np.ndarray:
    """The nodes left within 10 mm of the cavity's wall."""
    from scipy.spatial import cKDTree

    alive = np.unique(truth.present)
    distance, _ = cKDTree(truth.points[truth.wall]).query(truth.points[alive])
    mask = np.zeros(len(truth.points), dtype=bool)
    mask[alive[distance < 0.01]] = True
    return mask


def cavity_picture(out: Path, truth, errors: dict, near: np.ndarray) -> None:
    """The error in the sagittal slice through the cavity's centre, each way (near: the nodes
    the means are over)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = truth.points * 1e3
    centre = points[np.unique(truth.removed)].mean(axis=0)
    planes = np.unique(points[:, 0])
    x = planes[np.argmin(np.abs(planes - centre[0]))]
    alive = np.zeros(len(points), dtype=bool)
    alive[np.unique(truth.present)] = True
    plane = (np.abs(points[:, 0] - x) < 1e-6) & alive
    gone = (np.abs(points[:, 0] - x) < 1e-6) & ~alive
    vmax = float(np.ceil(max(errors["prediction"][plane].max(), 1.0)))
    fig, axes = plt.subplots(1, len(errors), figsize=(5.5 * len(errors), 5), layout="constrained")
    for ax, (name, e) in zip(axes, errors.items()):
        s = ax.scatter(points[plane, 2], points[plane, 1], c=e[plane], cmap="magma_r", vmin=0, vmax=vmax, s=14)
        ax.scatter(points[gone, 2], points[gone, 1], marker="x", c="tab:blue", s=14, label="removed")
        ax.set_title(f"{name}\nwithin 10 mm of the wall: mean {e[near].mean():.2f} mm", fontsize=10)
        ax.set_xlabel("z (S, mm)")
        ax.set_ylabel("y (A, up, mm)")
        ax.set_aspect("equal")
    axes[0].legend(loc="lower left", fontsize=8)
    fig.colorbar(s, ax=axes, shrink=0.8).set_label("error against the truth (mm)")
    fig.suptitle(f"sagittal slice x = {x:.0f} mm through the cavity ({truth.removed_ml:.1f} ml removed)", fontsize=10)
    fig.savefig(out / "cavity.png", dpi=90)
    plt.close(fig)


# -


if __name__ == "__main__":
    sys.exit(main())
