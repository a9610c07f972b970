"""`brainshift fit SCENE --target ... --params ...`: the command around the calibration."""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..outputs.files import RunLock, check_writable, clear_run, write_json
from ..runner import run
from ..scene import load_scene
from .calibrate import check_enough, fit
from .forward import ForwardModel
from .parameters import check_names, parameters, scene_changes
from .report import write_fit_json, write_fitted_scene
from .targets import read_target


def fit_command(args, comm) -> list[str]:
    """`brainshift fit` (arguments: cli.py); returns the report's lines (cli prints them)."""
    out = Path(args.out)
    check_writable(out, comm)
    names = [n.strip() for n in args.params.split(",") if n.strip()]
    check_names(names)
    if not 0 < args.noise < float("inf"):
        raise InputError(f"--noise must be a finite number of mm > 0 (got {args.noise:g})")
    target = read_target(args.target, args.pre, args.frame)
    check_enough(target, len(names))  # (before the model is built: nothing else is said first)
    scene = load_scene(args.scene, args.set)
    forward = ForwardModel(load_scene(args.scene, args.set + ["time.mode=quasi-static"]), comm)
    params = parameters(scene, names, forward.heights())
    result = fit(forward, target, params, args.noise * 1e-3)
    surface = forward.measured_surface if target.pre is None else None
    forward.destroy()
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    lock = RunLock(out, comm)  # one writer at a time; its earlier run and fit cleared (an update's folder refused)
    try:
        clear_run(out, comm, scene.name, keep=[Path(args.scene)] if Path(args.scene).is_file() else [], kind="fit")
        values = dict(zip(names, (float(v) for v in result.values)))
        fitted = write_fitted_scene(args.scene, args.set, scene_changes(scene, values), out) if comm.rank == 0 else None
        fitted = comm.bcast(fitted, root=0)
        write_fit_json(out, result, target, comm, surface)
        if not args.no_run:
            run(load_scene(fitted), out, comm, keep=[out / "fit.json", out / "fitted.toml"])
        else:  # (not "running": nothing else is coming)
            write_json(out / "summary.json", {"scene": scene.name, "status": "ok", "kind": "fit",
                                              "note": "--no-run: the fit alone, no fitted run"}, comm)
    finally:
        lock.release()
    report = result.as_dict()
    kind = target.kind + (f" (to {surface})" if surface else "")
    lines = [f"fit: {kind}, {len(target.measured)} points; {result.solves} settled states in "
             f"{result.seconds:.1f} s; residual RMS {report['prior_residual_rms_mm']:.2f} mm (scene) -> "
             f"{report['residual_rms_mm']:.2f} mm (fitted)"]
    for p, v, sd, ok, bound in zip(params, result.values, result.std, result.constrained, result.at_bound):
        if bound is not None:
            spread = (f"AT ITS {bound.upper()} BOUND: the points would take it past {p.lower if bound == 'lower' else p.upper:g} "
                      f"(not a measurement)")
        else:
            spread = f"+- {sd:.3g}" if ok else "NOT CONSTRAINED by these points (the value is not a measurement)"
        lines.append(f"  {p.name:16s} {p.prior:10.4g} -> {v:10.4g} {p.unit:4s} {spread}")
    if result.warning:
        lines.append(f"  WARNING: {result.warning}")
    lines.append(f"wrote {out}/fitted.toml, fit.json" + ("" if args.no_run else " and the fitted run"))
    return lines
