"""The ``brainshift`` command: the options every command shares, the dispatch to the
command's module (commands/), and what each kind of failure prints and exits with.
``main(argv) -> int``; tests call it directly."""

from __future__ import annotations

import argparse
import sys
from importlib import import_module

from .commands import NAMES
from .commands.help_format import Defaults, Parser
from .version import __version__


def parser() -> argparse.ArgumentParser:
    """The parser of every command (each module's ``add``)."""
    top = Parser(
        prog="brainshift",
        description="Predict brain shift (or any soft body sagging as its supporting fluid drains) with DOLFINx.",
        formatter_class=Defaults,
    )
    top.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    top.add_argument(
        "--log-level",
        default="INFO",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="how much to say (rank 0 only)",
    )
    top.add_argument("--log-all-ranks", action="store_true", help="let every MPI rank log")
    top.add_argument(
        "--no-progress", action="store_true", help="no progress bar (it shows on rank 0 only when stderr is a terminal)"
    )
    sub = top.add_subparsers(dest="command", required=True)
    for name in NAMES:
        import_module(f".commands.{name}", __package__).add(sub)
    return top


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    from . import logs
    from .errors import InputError, Interrupted, SolverError, write_failed

    command = import_module(f".commands.{args.command}", __package__)
    one_process = getattr(command, "ONE_PROCESS", False)  # (no MPI started: much of the service's start-up)
    logs.configure(args.log_level, args.log_all_ranks, one_process)
    if args.no_progress:
        from .outputs import progress

        progress.ENABLED = False
    if one_process:
        comm = OneProcess()
    else:
        from mpi4py import MPI

        comm = MPI.COMM_WORLD
    try:
        _check_finite(args)
        lines = command.main(args, comm)
        if comm.rank == 0 and lines:
            print("\n".join(lines))
        return 0
    except InputError as exc:  # bad input: nothing was written
        if comm.rank == 0:
            print(f"brainshift: error: {exc}", file=sys.stderr)
        return 2
    except Interrupted as exc:  # Ctrl-C during the run: its last good state was written
        if comm.rank == 0:
            print(f"brainshift: {exc}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:  # Ctrl-C before or after the run's loop
        if comm.rank == 0:
            print("brainshift: interrupted (Ctrl-C)", file=sys.stderr)
        return 130
    except SolverError as exc:  # the run stopped: the last good state was written
        if comm.rank == 0:
            print(f"brainshift: stopped: {exc}", file=sys.stderr)
        return 3
    except (OSError, RuntimeError) as exc:  # a file that could not be written mid-way: a full disk, a quota
        if not write_failed(exc):
            raise
        if comm.rank == 0:
            if isinstance(exc, OSError):
                what = f"{exc.strerror or exc}" + (f" '{exc.filename}'" if exc.filename else "")
            else:  # (a C++ writer's message: its first line says which file)
                what = f"a file could not be written ({str(exc).strip().splitlines()[0][:200]})"
            note = (
                ' (a run\'s summary.json says "running", not "ok": its files are incomplete)'
                if args.command in ("run", "fit", "update")
                else ""
            )
            print(f"brainshift: error: {what}: free space or choose another folder{note}", file=sys.stderr)
        if comm.size > 1:  # a write fails on the rank that writes: the others wait in its barrier
            sys.stderr.flush()
            comm.Abort(1)
        return 1


class OneProcess:
    """The communicator of a command that runs as one process (ONE_PROCESS in its module)."""

    rank, size = 0, 1

    def barrier(self) -> None:
        pass

    def bcast(self, value, root: int = 0):
        return value

    def Abort(self, code: int = 1) -> None:  # noqa: N802 (MPI's name)
        raise SystemExit(code)


def _check_finite(args) -> None:
    """Every number given on the command line is finite: argparse's float() takes "nan" and
    "inf", which then ran on (compare wrote NaN into its JSON) or named the wrong fix."""
    import math

    from .errors import InputError

    for key, value in vars(args).items():
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(v, float) and not math.isfinite(v):
                raise InputError(f"--{key.replace('_', '-')}: {v} is not a finite number")


if __name__ == "__main__":
    sys.exit(main())
