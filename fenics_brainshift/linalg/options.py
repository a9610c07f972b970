"""PETSc options: put into PETSc's database for one setup, checked, then taken out again.

A scene's ``[solver] options`` go under the solver's prefix. PETSc silently ignores an
option no object asks for (a typo, or one that belongs to another solver kind), so after
setup each one is looked up with PETSc's own ``PetscOptionsUsed``; what nothing used is bad
input. Viewers and monitors (``ksp_view``, ``ksp_monitor``, ``*_converged_reason``) are read
only when a solve ends, so they count as used.
"""

from __future__ import annotations

import ctypes
import re
from contextlib import contextmanager

from petsc4py import PETSc

_READ_AT_SOLVE = re.compile(r"(view|monitor|converged_reason|_draw)")


def option_text(value) -> str:
    """A TOML value as PETSc reads it: true is the bare flag (a boolean or a viewer's
    default, on every PETSc version), false is "false"."""
    if isinstance(value, bool):
        return "" if value else "false"
    return str(value)


@contextmanager
def options_in_database(values: dict[str, str]):
    """Insert name -> value (names with their prefix, no leading '-') for the block, then
    remove them, so one solver's options never leak into the next made in this process."""
    opts = PETSc.Options()
    for key, value in values.items():
        opts.setValue(key, value)
    try:
        yield
    finally:
        for key in values:
            opts.delValue(key)


def unused(names) -> list[str]:
    """The names PETSc's database holds but no object has read (empty if PETSc's library
    cannot be found to ask)."""
    library = _petsc_library()
    if library is None:
        return []
    left = []
    for name in names:
        if _READ_AT_SOLVE.search(name):
            continue
        used = ctypes.c_int(0)
        if library.PetscOptionsUsed(None, name.encode(), ctypes.byref(used)) == 0 and not used.value:
            left.append(name)
    return left


_LIBRARY: list = []


def _petsc_library():
    """The libpetsc that petsc4py loaded (found in this process's memory map)."""
    if not _LIBRARY:
        path = None
        try:
            with open("/proc/self/maps") as maps:
                path = next((line.split()[-1] for line in maps if "/libpetsc" in line), None)
        except OSError:
            pass
        _LIBRARY.append(ctypes.CDLL(path) if path else None)
    return _LIBRARY[0]
