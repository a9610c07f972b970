"""A progress bar on rank 0 for time loops and sweeps, silent when stderr is not a terminal
or when switched off (`brainshift --no-progress`), and without tqdm it is simply absent."""

from __future__ import annotations

import sys

ENABLED: bool | None = None  # None: only when stderr is a terminal


class _Silent:
    def __init__(self, iterable):
        self.iterable = iterable

    def __iter__(self):
        return iter(self.iterable)

    def set_postfix_str(self, text: str, refresh: bool = True) -> None:
        pass

    def close(self) -> None:
        pass


def progress(iterable, desc: str, total: int | None = None, unit: str = "step"):
    """tqdm(iterable) on rank 0 when enabled, else the iterable itself (same methods)."""
    from mpi4py import MPI

    show = sys.stderr.isatty() if ENABLED is None else ENABLED
    if not show or MPI.COMM_WORLD.rank != 0:
        return _Silent(iterable)
    try:
        from tqdm import tqdm
    except ImportError:
        return _Silent(iterable)
    return tqdm(iterable, desc=desc, total=total, unit=unit, leave=False, dynamic_ncols=True, file=sys.stderr)
