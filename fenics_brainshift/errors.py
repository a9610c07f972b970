"""Every error the package raises on purpose, in one place.

- InputError: bad input (a scene value, a file, a command-line argument, a resource the
  machine does not have). Its message is one line that names the field and the fix; the CLI
  prints it and exits with code 2, and nothing has been written.
- SolverError: a run that went wrong (a diverged solve, a guard that fired). The CLI exits
  with code 3, and the last good state is kept.
- Interrupted: the user stopped the run (Ctrl-C): the last good state is kept, the summary
  says "interrupted", and the CLI exits with code 130 (as a shell does for SIGINT).

Any other exception is a bug; under mpirun ``abort_on_uncaught`` makes it end the whole job.
"""

from __future__ import annotations

import sys

__all__ = ["BrainshiftError", "InputError", "Interrupted", "SolverError", "abort_on_uncaught"]


class BrainshiftError(Exception):
    """Base of the package's own errors."""


class InputError(BrainshiftError, ValueError):
    """Bad input; the one-line message names the field (e.g. ``[material] E``) and the fix."""


class SolverError(BrainshiftError, RuntimeError):
    """A run stopped: a solve diverged or a guard fired; the message says why."""


class Interrupted(SolverError):
    """The run was interrupted (Ctrl-C); the last good state was kept."""


# What the C++ writers say when a file cannot be written (a full disk, a quota, a folder
# gone): DOLFINx's HDF5 and VTK writers (0.5 and 0.9) and ITK's. Specific phrases, not "write":
# DOLFINx's "Cannot write sub-Functions to VTK file" is a program's error and must stay loud.
WRITER_FAILURES = (
    "failed to write",
    "could not write",
    "h5dwrite",
    "failed to create hdf5",
    "failed to create/open hdf5",
    "failed to close hdf5",
    "failed to flush hdf5",
    "failed to create director",
    "imagefilewriter",
    "transformfilewriter",
    "could not create io object for writing",
    "no space left",
    "quota exceeded",
)


def write_failed(exc: BaseException) -> bool:
    """Whether an exception is a file that could not be written: an OSError, or the
    RuntimeError a C++ writer raises instead (WRITER_FAILURES)."""
    if isinstance(exc, OSError):
        return True
    if not isinstance(exc, RuntimeError) or isinstance(exc, BrainshiftError):
        return False
    message = str(exc).lower()
    return any(phrase in message for phrase in WRITER_FAILURES)


def abort_on_uncaught() -> None:
    """Under mpirun, an exception nobody catches on one rank ends that rank, and MPI's
    finalisation at its exit waits for ranks that wait in their next collective for it: the
    job hangs with the traceback unread. This hook prints the traceback, then aborts every
    rank (as ``python -m mpi4py`` does). Installed by the entry points (logs.configure);
    idempotent; on one rank it changes nothing."""
    if getattr(sys.excepthook, "aborts_mpi", False):
        return
    previous = sys.excepthook

    def hook(kind, value, traceback):
        try:
            previous(kind, value, traceback)
        finally:  # even if the traceback cannot be printed (stderr closed), the job must end
            MPI = sys.modules.get("mpi4py.MPI")
            if MPI is not None and MPI.Is_initialized() and not MPI.Is_finalized() and MPI.COMM_WORLD.size > 1:
                try:
                    sys.stderr.write(f"[rank {MPI.COMM_WORLD.rank}] an uncaught {kind.__name__}: aborting every rank\n")
                    sys.stderr.flush()
                except Exception:
                    pass
                MPI.COMM_WORLD.Abort(130 if issubclass(kind, KeyboardInterrupt) else 1)

    hook.aborts_mpi = True
    sys.excepthook = hook
