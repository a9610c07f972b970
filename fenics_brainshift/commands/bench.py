"""`brainshift bench`: run time against error over a sweep of configurations, on one rank."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .help_format import Defaults


def add(sub) -> None:
    bench = sub.add_parser(
        "bench",
        help="run time against error: a sweep of configurations, Pareto front",
        description="Every configuration computes the final shift of the scene; its run time "
        "(scene to answer) and its error against a fine P2 reference at fixed "
        "sample points go to DIR/time_vs_error_SCENE.csv, .md and .png, with the "
        "paper-equivalent configuration and a naive loop as baselines in the same "
        "run.",
        formatter_class=Defaults,
    )
    bench.add_argument(
        "--scene",
        choices=["cube", "brain"],
        default="cube",
        help="the gelatin cube at 10 ml, or the bundled brain after the CSF has drained",
    )
    size = bench.add_mutually_exclusive_group()
    size.add_argument(
        "--quick",
        action="store_true",
        help="coarser meshes and fewer configurations (cube: about a minute; brain: about 11 min, "
        "mostly the paper-equivalent CG)",
    )
    size.add_argument("--smoke", action="store_true", help="tiny meshes: a few seconds, to check that the sweep runs")
    bench.add_argument("--out", default="bench_results", help="output folder")
    bench.add_argument(
        "--only",
        action="append",
        metavar="NAME",
        help="run only this configuration (repeatable) and merge its row into the table already "
        "in --out, keeping the other rows as measured",
    )


def main(args, comm) -> list[str]:
    """Sweep, write the tables and the plot; returns the line naming the most accurate."""
    from ..bench import run_sweep
    from ..outputs.files import check_writable
    from ..outputs.progress import progress

    if comm.size > 1:
        raise InputError(
            "bench: run it on one rank (it compares configurations; benchmarks/cube_sizes.py measures ranks)"
        )
    out = Path(args.out)
    check_writable(out, comm)
    level = "smoke" if args.smoke else "quick" if args.quick else "full"
    rows = run_sweep(args.scene, level, out, progress, args.only)
    best = min(rows, key=lambda r: r["max_error_mm"])
    return [
        f"bench {args.scene}: {len(rows)} configurations; most accurate {best['config']} "
        f"({best['max_error_mm']:.3f} mm, {best['total_s']:.2f} s); wrote {out}/time_vs_error_{args.scene}.md, "
        f".csv and .png"
    ]
