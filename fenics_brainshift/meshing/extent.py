"""A body's size, and the unit slip a size no soft-tissue body has betrays (a mm brain read as
metres is 170 m across). One rule for `brainshift run` and `brainshift mesh`."""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

from ..units import LENGTH_UNITS

BODY_SIZE = (2e-3, 3.0)  # m across: a body outside this range is a unit slip (a brain is 0.1-0.2 m)
PLAUSIBLE = (0.02, 0.5)  # m across: the size a unit guess must give (phantoms to a whole head)


def body_diagonal(mesh) -> float:
    """The diagonal of the body's bounding box (m), on every rank."""
    comm, x = mesh.comm, mesh.geometry.x
    lo = [comm.allreduce(float(v), op=MPI.MIN) for v in x.min(axis=0, initial=np.inf)]
    hi = [comm.allreduce(float(v), op=MPI.MAX) for v in x.max(axis=0, initial=-np.inf)]
    return float(np.linalg.norm(np.subtract(hi, lo)))


def size_problem(size: float, scale: float) -> tuple[str, str | None] | None:
    """None for a body ``size`` m across within BODY_SIZE, else (what it is, the unit — one of
    LENGTH_UNITS — that would make the input ``size / scale`` a plausible body, or None)."""
    small, large = BODY_SIZE
    if small <= size <= large:
        return None
    raw = size / scale  # across, in the input's own numbers
    guesses = [
        u for u, f in LENGTH_UNITS.items() if PLAUSIBLE[0] <= raw * f <= PLAUSIBLE[1] and not np.isclose(f, scale)
    ]
    what = f"the body is {size:.3g} m across ({small:g}-{large:g} m expected; a brain is 0.1-0.2 m)"
    return what, (guesses[0] if guesses else None)
