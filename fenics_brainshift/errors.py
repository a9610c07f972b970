"""Every error the package raises on purpose, in one place.

- InputError: bad input (a scene value, a file, a command-line argument, a resource the
  machine does not have). Its message is one line that names the field and the fix; the CLI
  prints it and exits with code 2, and nothing has been written.
- SolverError: a run that went wrong (a diverged solve, a guard that fired). The CLI exits
  with code 3, and the last good state is kept.
- Interrupted: the user stopped the run (Ctrl-C): the last good state is kept, the summary
  says "interrupted", and the CLI exits with code 130 (as a shell does for SIGINT).
"""
from __future__ import annotations

__all__ = ["BrainshiftError", "InputError", "Interrupted", "SolverError"]


class BrainshiftError(Exception):
    """Base of the package's own errors."""


class InputError(BrainshiftError, ValueError):
    """Bad input; the one-line message names the field (e.g. ``[material] E``) and the fix."""


class SolverError(BrainshiftError, RuntimeError):
    """A run stopped: a solve diverged or a guard fired; the message says why."""


class Interrupted(SolverError):
    """The run was interrupted (Ctrl-C); the last good state was kept."""
