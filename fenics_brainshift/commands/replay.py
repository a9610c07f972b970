"""`brainshift replay DIR --atlas ATLAS`: re-run an operation recorded by `brainshift serve
--record DIR` and check that every update gives the recorded answer."""

from __future__ import annotations

from pathlib import Path

from .help_format import Defaults

ONE_PROCESS = True  # (the CLI starts no MPI for it; launched by mpirun it refuses)


def add(sub) -> None:
    replay = sub.add_parser(
        "replay",
        formatter_class=Defaults,
        help="re-run an operation recorded by serve --record and check it gives the same answers",
        description="Feed the messages recorded in DIR through the same sessions as the server, with the same "
        "options, and check that each update gives the recorded weights and residuals (to 1e-9).",
    )
    replay.add_argument("record", help="the folder of `brainshift serve --record`")
    replay.add_argument("--atlas", required=True, help="the atlas the operation was served with")
    replay.add_argument("--pre", help="as given to serve")
    replay.add_argument("--targets", help="as given to serve")
    replay.add_argument("--frame", type=str.upper, choices=["RAS", "LPS"], default="RAS", help="as given to serve")
    replay.add_argument("--noise", type=float, default=1.0, help="as given to serve, mm")
    replay.add_argument("--grid", type=float, default=4.0, help="as given to serve, mm")
    replay.add_argument("--share", action="store_true", help="as given to serve")
    replay.add_argument("--stage", type=int, default=0, help="as given to serve")
    replay.add_argument("--structure", action="append", default=[], metavar="NAME=FILE", help="as given to serve")


def main(args, comm) -> list[str]:
    from ..images.targets import check_noise
    from ..theatre.record import replay
    from .serve import session_factory

    check_noise(args.noise, "--noise")
    folder = Path(args.record)
    new_session, options = session_factory(args)
    return replay(folder, new_session, options)
