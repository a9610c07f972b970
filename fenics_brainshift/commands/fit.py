"""`brainshift fit SCENE --target ... --params ...`: the command around the calibration."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .help_format import Defaults, add_overwrite


def add(sub) -> None:
    fit = sub.add_parser(
        "fit",
        help="calibrate: fit the CSF level, G and the head pose to intra-operative points",
        description="Robust least squares of the measured points against the scene's settled state "
        "after the drain (point to point with --pre, else point to the predicted "
        "surface); one factorisation for every evaluation. Writes OUT/fitted.toml, "
        "OUT/fit.json (values, uncertainties, residuals) and the fitted scene's run.",
        formatter_class=Defaults,
    )
    fit.add_argument("scene", help="scene file or bundled scene name")
    fit.add_argument(
        "--target",
        required=True,
        help="measured intra-operative points (mm): .mrk.json, .csv or a surface (.vtk, .stl, ...)",
    )
    fit.add_argument("--pre", help="the same points before the shift (.mrk.json, matched by label): point to point")
    fit.add_argument(
        "--params",
        required=True,
        help="comma-separated: fluid.level, material.G, gravity.angle_x, gravity.angle_y, gravity.angle_z",
    )
    fit.add_argument(
        "--frame",
        type=str.upper,
        choices=["RAS", "LPS"],
        default=None,
        help="the frame of a CSV target and of a surface target whose header does not say (Slicer "
        "writes SPACE= in it); default RAS. Markups files carry their own",
    )
    fit.add_argument("--noise", type=float, default=1.0, help="measurement noise (mm): the robust loss's scale")
    fit.add_argument("--out", default="out_fit", help="output folder")
    fit.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="scene overrides")
    fit.add_argument("--no-run", action="store_true", help="fit only; do not run the fitted scene")
    add_overwrite(fit, "the fit's folder")


def main(args, comm) -> list[str]:
    """`brainshift fit`: calibrate, write OUT, and return the report's lines."""
    from ..fit.calibrate import check_enough, fit
    from ..fit.forward import ForwardModel
    from ..fit.parameters import check_names, fit_parameters, scene_changes
    from ..fit.report import write_fit_json, write_fitted_scene
    from ..images.targets import check_noise, read_target
    from ..outputs.files import RunLock, check_writable, clear_run, write_json
    from ..runner import run
    from ..scene import load_scene

    out = Path(args.out)
    check_writable(out, comm)
    names = [n.strip() for n in args.params.split(",") if n.strip()]
    check_names(names)
    check_noise(args.noise)
    target = read_target(args.target, args.pre, args.frame)
    check_enough(target, len(names))  # (before the model is built: nothing else is said first)
    scene = load_scene(args.scene, args.set)
    if scene.remove:  # (its settled states would measure the points against the surface before the cut)
        raise InputError(
            "fit: a scene with [[remove]] is not fitted (the points would be measured against the brain before the "
            "cut); fit the scene before the resection, or build an atlas with its resection stages (brainshift "
            "atlas SCENE --resect REGION) and update it"
        )
    forward = ForwardModel(load_scene(args.scene, args.set + ["time.mode=quasi-static"]), comm)
    params = fit_parameters(scene, names, forward.heights())
    result = fit(forward, target, params, args.noise * 1e-3)
    surface = forward.measured_surface if target.pre is None else None
    forward.destroy()
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    lock = RunLock(out, comm)  # one writer at a time; its earlier run and fit cleared (an update's folder refused)
    try:
        keep = [Path(args.scene)] if Path(args.scene).is_file() else []
        clear_run(out, comm, scene.name, keep=keep, kind="fit", overwrite=args.overwrite)
        values = dict(zip(names, (float(v) for v in result.values)))
        fitted = write_fitted_scene(args.scene, args.set, scene_changes(scene, values), out) if comm.rank == 0 else None
        fitted = comm.bcast(fitted, root=0)
        write_fit_json(out, result, target, comm, surface)
        if not args.no_run:
            run(load_scene(fitted), out, comm, keep=[out / "fit.json", out / "fitted.toml"])
        else:  # (not "running": nothing else is coming)
            write_json(
                out / "summary.json",
                {"scene": scene.name, "status": "ok", "kind": "fit", "note": "--no-run: the fit alone, no fitted run"},
                comm,
            )
    finally:
        lock.release()
    report = result.as_dict()
    kind = target.kind + (f" (to {surface})" if surface else "")
    lines = [
        f"fit: {kind}, {len(target.measured)} points; {result.solves} settled states in "
        f"{result.seconds:.1f} s; residual RMS {report['prior_residual_rms_mm']:.2f} mm (scene) -> "
        f"{report['residual_rms_mm']:.2f} mm (fitted)"
    ]
    for p, v, sd, ok, bound in zip(params, result.values, result.std, result.constrained, result.at_bound):
        if bound is not None:
            spread = (
                f"AT ITS {bound.upper()} BOUND: the points would take it past "
                f"{p.lower if bound == 'lower' else p.upper:g} "
                f"(not a measurement)"
            )
        else:
            spread = f"+- {sd:.3g}" if ok else "NOT CONSTRAINED by these points (the value is not a measurement)"
        lines.append(f"  {p.name:16s} {p.prior:10.4g} -> {v:10.4g} {p.unit:4s} {spread}")
    if result.warning:
        lines.append(f"  WARNING: {result.warning}")
    lines.append(f"wrote {out}/fitted.toml, fit.json" + ("" if args.no_run else " and the fitted run"))
    return lines
