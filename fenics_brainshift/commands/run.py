"""`brainshift run SCENE`: a scene's simulation, written to its output folder."""

from __future__ import annotations

from pathlib import Path

from .help_format import Defaults, add_overwrite


def add(sub) -> None:
    run = sub.add_parser("run", help="run a scene file (also under mpirun -n N)", formatter_class=Defaults)
    run.add_argument("scene", help="scene TOML file, or a bundled scene by name (brainshift scenes)")
    run.add_argument("--out", help="output folder (default: the scene's [output] folder)")
    run.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override a scene value, e.g. --set time.end=2 --set solver.kind=cholesky "
        "(repeatable; arrays by index: fixed.0.where='z < 0.01')",
    )
    run.add_argument(
        "--pictures",
        action="store_true",
        help="also write deformed.png and probes.png (same as --set output.pictures=true)",
    )
    add_overwrite(run, "the run's folder")


def main(args, comm) -> list[str]:
    """Run the scene; returns the line with its largest shift and probes."""
    from ..runner import run
    from ..scene import load_scene

    scene = load_scene(args.scene, args.set + (["output.pictures=true"] if args.pictures else []))
    out = args.out or scene.output.folder
    keep = [Path(args.scene)] if Path(args.scene).is_file() else []  # (a fit's fitted.toml, run where it was fitted)
    summary = run(scene, out, comm, keep=keep, overwrite=args.overwrite).summary
    probes = ", ".join(f"{k}=[{', '.join(f'{c * 1e3:.3f}' for c in v)}] mm" for k, v in summary["probes"].items())
    return [
        f"{scene.name}: max |u| = {summary['max_displacement_m'] * 1e3:.3f} mm"
        + (f"; {probes}" if probes else "")
        + f"; wrote {out}/summary.json"
    ]
