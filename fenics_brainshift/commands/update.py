"""`brainshift update ATLAS --target T --out OUT`: the update, written as a run folder that
`brainshift warp` takes (displacement.xdmf with the per-node uncertainty beside it, the moved
fine surface, the probes and the measured markups moved), and OUT/update.json."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..atlas import store
from ..atlas.stages import fit_stages, load_stages, parse_stage, removed, stage_line
from ..atlas.update import coordinates
from ..atlas.update_files import uncertainty_grid, write_outputs
from ..errors import InputError
from ..images.targets import check_noise, read_surface_points, read_target, with_surface_points
from ..outputs.files import RunLock, check_writable, clear_run, runs_results, write_json
from ..theatre.case import Case
from .help_format import Defaults, add_overwrite

DEFAULT_NOISE_MM = 1.0  # a tracked pointer's error on the cortex
NEAR_MM = 20.0  # the uncertainty's headline: the nodes this close to a measured point


def add(sub) -> None:
    update = sub.add_parser(
        "update",
        formatter_class=Defaults,
        help="in theatre: fit the atlas's modes to intra-operative measurements, in "
        "milliseconds; writes a run folder for warp",
        description="Fit the weights of the atlas's modes to measured points (point to point: "
        "--pre and --target .mrk.json by label, a CSV with x_pre.. columns, an MNI "
        ".tag of landmark pairs; point to surface: points or a scanned surface) as "
        "a constrained least-squares problem; alpha by "
        "cross-validation. Writes OUT/displacement.xdmf (with the per-node "
        "uncertainty), OUT/update.json, the moved surface and markups.",
    )
    update.add_argument("atlas", help="atlas folder (brainshift atlas SCENE -o ATLAS)")
    update.add_argument(
        "--target",
        required=True,
        help="measured intra-operative points (mm): .mrk.json, .csv, .tag or a surface (.stl, .vtk, .ply, ...)",
    )
    update.add_argument("--pre", help="the same points before the shift (.mrk.json, matched by label)")
    update.add_argument(
        "--frame",
        type=str.upper,
        choices=["RAS", "LPS"],
        default=None,
        help="frame of a CSV or an untagged surface target (default RAS)",
    )
    update.add_argument(
        "--noise",
        type=float,
        default=None,
        help="measurement noise of a point, mm per coordinate (default 1, a tracked pointer's; "
        "the report says which was used)",
    )
    update.add_argument(
        "--bootstrap",
        type=int,
        default=0,
        help="the uncertainty from this many resamplings of the points (a refit each) instead of "
        "the weights' posterior (default: 0, the posterior, in closed form)",
    )
    update.add_argument(
        "--keep-all",
        action="store_true",
        help="fit every point: none set aside as an outlier (by default a point whose "
        "left-out error is far past the noise and the others' is set aside and reported)",
    )
    update.add_argument(
        "--stage",
        default=None,
        help="an atlas with resection stages (atlas --resect): the stage to fit, 0 (before the resection), 1, 2, "
        "...; default auto: every stage fitted, the one that explains the points best kept (update.json says "
        "why)",
    )
    update.add_argument(
        "--cavity",
        help="points on the resection cavity's wall (intra-operative ultrasound; mm: .mrk.json, .csv or a "
        "surface), fitted to the stage's surface, the cavity's wall included",
    )
    update.add_argument(
        "--cavity-frame",
        type=str.upper,
        choices=["RAS", "LPS"],
        default=None,
        help="frame of a CSV or untagged surface --cavity (default: --frame's, else RAS)",
    )
    update.add_argument("--image", help="a volume (.nii.gz, .nrrd) on whose grid to write OUT/uncertainty.nii.gz")
    update.add_argument("--out", default="out_update", help="output folder")
    add_overwrite(update, "the update's folder", "--replace")


def main(args, comm) -> list[str]:
    """`brainshift update`: fit, write OUT, and return the report's lines."""
    start = time.perf_counter()
    out = Path(args.out)
    check_writable(out, comm)
    _check_no_earlier_update(out, args.overwrite, comm)
    noise_stated = args.noise is not None
    args.noise = args.noise if noise_stated else DEFAULT_NOISE_MM
    check_noise(args.noise)
    if not 0 <= args.bootstrap <= 1000:
        raise InputError(f"--bootstrap: the number of resamplings, 0 to 1000 (got {args.bootstrap})")
    image = None
    if args.image is not None:
        from ..images.volumes import read_volume

        image = read_volume(args.image, "update: --image")
    told = parse_stage(args.stage)
    atlas = store.read(args.atlas)  # every rank: the update is small, each computes it, rank 0 writes
    staged = store.stage_count(atlas) > 0
    if told == 0 and args.cavity is not None:
        raise InputError(
            "--cavity with --stage 0: before the resection there is no cavity's wall to fit the points to; give "
            "the stage (--stage K) or let the update choose (--stage auto)"
        )
    if args.cavity is not None and not staged:
        raise InputError(
            f"--cavity: the atlas in '{args.atlas}' has no resection stages, so no cavity to fit the points to; "
            f"build them with brainshift atlas SCENE --resect REGION"
        )
    target = read_target(args.target, args.pre, args.frame)
    if args.cavity is not None:
        frame = args.cavity_frame or args.frame
        target = with_surface_points(target, read_surface_points(args.cavity, frame, "--cavity"), "cavity")
    cases = []

    def fit(stage_atlas, alpha=None):  # (the case prepares the atlas once, as `brainshift serve` keeps it prepared)
        case = Case(
            stage_atlas, noise=args.noise * 1e-3, grid=None, samples=args.bootstrap, set_aside=not args.keep_all
        )
        cases.append(case)
        return case.update(target, alpha)

    whole = None  # (a stage's atlas holds the cells left: the whole mesh's are the atlas's before)
    if staged or told:
        whole = atlas.tetrahedra
        stages = load_stages(args.atlas, atlas, told)
        number, atlas, answer, evidence = fit_stages(stages, fit, args.noise * 1e-3, coordinates(target))
        whole = whole if number else None
        case = next(c for c in cases if c.atlas is atlas)
        args.stage_report = {"number": number, "told": told is not None, "evidence": evidence, **removed(atlas)}
    else:
        answer = fit(atlas)
        case = cases[0]
        args.stage_report = None
    result = answer.result
    result.seconds["atlas_prepare_ms"] = case.prepare_s * 1e3
    args.noise_stated = noise_stated
    # what can fail is done on every rank before a file is touched
    spread_image = uncertainty_grid(atlas, result.spread, image) if image is not None else None
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    lock = RunLock(out, comm)
    try:
        scene_name = atlas.info.get("scene_name", "atlas")
        clear_run(out, comm, scene_name, kind="update", overwrite=args.overwrite)  # (an earlier update's files too)
        if comm.rank == 0:
            write_outputs(out, atlas, target, result, image, spread_image, whole)
        comm.barrier()
        report = _report(atlas, target, result, args, time.perf_counter() - start)
        report["suggestion"] = _suggestion(answer, case)
        write_json(out / "update.json", report, comm)
        write_json(
            out / "summary.json",
            {
                "scene": atlas.info.get("scene_name"),
                "status": "ok",
                "kind": "update",
                "atlas": str(Path(args.atlas).resolve()),
                "warning": result.warning,
            },
            comm,
        )
    finally:
        lock.release()
    lines = _lines(atlas, target, result, out, image is not None, args)
    if not noise_stated:
        lines.insert(
            1, f"  noise: {DEFAULT_NOISE_MM:g} mm per coordinate, the default (--noise to state the measurement's own)"
        )
    return lines


def _check_no_earlier_update(out: Path, overwrite: bool, comm) -> None:
    """An update's folder is the record of what guided the operation at that moment: a second
    update into it, or an update into a run's results, is refused unless asked for (--overwrite)."""
    if comm.bcast((out / "atlas.h5").is_file() if comm.rank == 0 else None, root=0):
        raise InputError(f"--out '{out}' holds an atlas (atlas.h5): give the update a folder of its own")
    if overwrite:
        return
    earlier = None
    if comm.rank == 0 and (out / "update.json").is_file():
        import json

        try:
            made = json.loads((out / "update.json").read_text())
            earlier = f"{made.get('points', '?')} points, {made.get('target', '?')}"
        except (OSError, ValueError):
            earlier = "its update.json unreadable"
    problem = runs_results(out) if comm.rank == 0 else None  # (before the fit, not after it)
    problem = comm.bcast(problem, root=0)
    if problem:
        raise InputError(problem)
    earlier = comm.bcast(earlier, root=0)
    if earlier is not None:
        raise InputError(
            f"--out '{out}' holds an earlier update ({earlier}): give each update its own --out "
            f"(out_update_2, ...), or --overwrite to replace it"
        )


def _spread_near(atlas, target, result) -> float:
    """The uncertainty where it is read: the mean spread (m) of the nodes within NEAR_MM of a
    measured point (the craniotomy and the targets), not the whole brain's mean (3-8 times the
    error near the craniotomy on a prepared patient)."""
    from scipy.spatial import cKDTree

    where = target.places  # (a point to the surface has no pre-operative point: a NaN row)
    near = cKDTree(where).query(atlas.points, distance_upper_bound=NEAR_MM * 1e-3)[0] < np.inf
    return float(result.spread[near].mean()) if near.any() else float(result.spread.mean())


def _kept(result) -> np.ndarray:
    """The points the fit used (not set aside as outliers)."""
    keep = np.ones(len(result.residual), dtype=bool)
    keep[result.outliers] = False
    return keep


def _report(atlas, target, result, args, seconds: float) -> dict:
    mm = 1e3
    keep = _kept(result)
    return {
        "atlas": str(Path(args.atlas).resolve()),
        "mesh_id": atlas.mesh_id(),
        "target": str(args.target),
        "kind": target.kind,
        "points": len(target.measured),
        "noise_mm": args.noise,
        "noise_stated": args.noise_stated,
        "alpha": result.alpha,
        "cross_validation": result.curve,
        "prior_residual_rms_mm": float(np.sqrt(np.mean(result.prior_residual[keep] ** 2))) * mm,
        "residual_rms_mm": float(np.sqrt(np.mean(result.residual[keep] ** 2))) * mm,
        "leave_one_out_rms_mm": float(np.sqrt(np.nanmean(result.leave_one_out[keep] ** 2))) * mm,
        "leave_one_out_points": int(np.count_nonzero(np.isfinite(result.leave_one_out[keep]))),
        "set_aside": [target.labels[i] for i in result.outliers],
        "per_point": [
            {"label": label, "prior_mm": p * mm, "updated_mm": r * mm, "left_out_mm": o * mm, "set_aside": not k}
            for label, p, r, o, k in zip(
                target.labels, result.prior_residual, result.residual, result.leave_one_out, keep
            )
        ],
        "family_weights": result.family_weights(atlas),
        "volume_changes": result.volume_changes(atlas),
        "stiffness_G_Pa": result.stiffness(atlas),
        "stiffness_range_Pa": atlas.info.get("stiffness"),
        "stiffness_at_bound": result.stiffness_at_bound(atlas),
        "weights": [float(c) for c in result.weights],
        "bootstrap_samples": args.bootstrap,
        "uncertainty_mm": {
            "from": result.spread_from,
            "near_points": _spread_near(atlas, target, result) * mm,
            "near_points_within_mm": NEAR_MM,
            "mean": float(result.spread.mean()) * mm,
            "max": float(result.spread.max()) * mm,
        },
        "largest_displacement_mm": float(np.linalg.norm(result.displacement, axis=1).max()) * mm,
        "largest_displacement_at_mm": [  # (the pre-operative position of the node that moves most, RAS)
            float(c) * mm for c in atlas.points[np.argmax(np.linalg.norm(result.displacement, axis=1))]
        ],
        "skull": result.skull,
        "timings_ms": result.seconds,
        "command_s": seconds,
        "warning": result.warning,
        "resection_stage": args.stage_report,
    }


def _suggestion(answer, case) -> dict | None:
    """Where a touch of the cortex would most lower the spread at the atlas's probes."""
    s = answer.suggestion
    if s is None:
        return None
    return {
        "position_ras_mm": [float(x) for x in s.position * 1e3],
        "targets": case.targets[0],
        "targets_spread_mm": s.spread * 1e3,
        "expected_spread_mm": s.expected * 1e3,
    }


def _lines(atlas, target, result, out: Path, image: bool, args=None) -> list[str]:
    rms = lambda r: float(np.sqrt(np.mean(r**2))) * 1e3  # noqa: E731
    keep = _kept(result)
    drained = (atlas.info.get("prior") or {}).get("fluid.level")

    def said(k, v):  # a level also in mm about the scene's drained level (the craniotomy rim's, for a patient)
        if k == "fluid.level" and drained is not None:
            return f"{k}={v:g} ({(v - drained) * 1e3:+.0f} mm about the scene's drained level)"
        return f"{k}={v:g}"

    top = ", ".join(
        f"{s['weight']:.2f} x " + " ".join(said(k, v) for k, v in s.items() if k != "weight")
        for s in result.family_weights(atlas)[:3]
    )
    lines = [
        f"update: {target.kind}, {len(target.measured)} points, {len(result.weights)} modes; residual RMS "
        f"{rms(result.prior_residual[keep]):.2f} mm (scene) -> {rms(result.residual[keep]):.2f} mm (updated), "
        f"left out {float(np.sqrt(np.nanmean(result.leave_one_out[keep] ** 2))) * 1e3:.2f} mm; fit "
        f"{result.seconds['weights_ms']:.0f} ms (alpha {result.alpha:g} by cross-validation), the whole update "
        f"{result.seconds['total_ms']:.0f} ms",
        f"  scenarios: {top or 'none'}",
    ]
    if result.stiffness(atlas) is not None:
        bound = result.stiffness_at_bound(atlas)
        lines.append(
            f"  stiffness: G = {result.stiffness(atlas):.4g} Pa (the scene's {atlas.info['stiffness']['G']:.4g}"
            + (f"; AT THE ATLAS'S {bound.upper()} BOUND: not a measurement)" if bound else ")")
        )
    for name, theta in result.volume_changes(atlas).items():
        lines.append(f"  swelling {name}: volume change {theta:+.3%}")
    if args is not None and args.stage_report is not None:
        lines.append(stage_line(args.stage_report))
    if result.skull:
        lines.append(
            f"  skull: {result.skull['nodes_with_rows']} nodes held inside by the fit's rows, deepest past "
            f"{result.skull['deepest_past_mm']:.2f} mm"
        )
    lines.append(
        f"  uncertainty ({result.spread_from}): {_spread_near(atlas, target, result) * 1e3:.2f} mm within "
        f"{NEAR_MM:g} mm of the measured points (mean of the nodes there); the whole brain's mean "
        f"{result.spread.mean() * 1e3:.2f} mm, largest {result.spread.max() * 1e3:.2f} mm"
    )
    if result.warning:
        lines.append(f"  WARNING: {result.warning}")
    lines.append(
        f"wrote {out}/displacement.xdmf, update.json"
        + (", uncertainty.nii.gz, update.png" if image else "")
        + f" (brainshift warp {out} --image PRE -o INTRA.nii.gz)"
    )
    return lines
