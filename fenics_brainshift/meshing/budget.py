"""Memory estimates made before anything large is allocated, checked against the machine.

A length in the wrong unit (a voxel of 0.005 given for a millimetre surface, `cells` in the
thousands) asks for terabytes; numpy would try, and the machine would swap or the process
die. Each estimate is compared with the memory available now and refused with the estimate
and the likely slip. The figures are estimates, on the generous side:

- a run needs about RUN_BYTES_PER_NODE per P1 node: 6.0 GB at 333k nodes (10^6 dofs) with
  CG + GAMG on 2 ranks (benchmarks/results/scaling.md), about 18 kB a node; P2 about ten
  times that per vertex (seven times the nodes, denser rows);
- the voxel mesher keeps a few arrays per coarse voxel (GRID_BYTES_PER_VOXEL) and, for a
  surface, a few per sample point (SAMPLE_BYTES: votes, masks, sort keys and counts).
"""

from __future__ import annotations

import os

from ..errors import InputError

RUN_BYTES_PER_NODE = 18e3
GRID_BYTES_PER_VOXEL = 40.0
SAMPLE_BYTES = 30.0


def available_bytes() -> float:
    """Memory available to a new allocation now (MemAvailable), or the machine's total."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def human(n_bytes: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if n_bytes < 1000.0 or unit == "PB":
            return f"{n_bytes:.3g} {unit}"
        n_bytes /= 1000.0
    return f"{n_bytes:.3g} PB"


def require(n_bytes: float, what: str, hint: str) -> None:
    """InputError if ``what`` would need more than the memory available."""
    have = available_bytes()
    if n_bytes > have:
        raise InputError(
            f"{what} would need about {human(n_bytes)} of memory, more than the {human(have)} available; {hint}"
        )


def run_bytes(nodes: float, degree: int = 1) -> float:
    """Estimated memory of a run on a mesh with this many vertices."""
    return nodes * RUN_BYTES_PER_NODE * (10.0 if degree == 2 else 1.0)
