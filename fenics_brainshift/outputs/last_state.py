"""OUT/last_state.npz: the run's latest complete state, replaced whole at every output time.

HDF5 keeps part of displacement.h5's index in memory until the file is closed, so a run
killed without warning (SIGKILL: the out-of-memory killer, a power cut) leaves that file
unreadable. This file is written beside it by rank 0 to a temporary name, synced to disk and
renamed over the last one, so whenever the run dies the folder holds one complete state:
the vertices and tetrahedra (in GlobalVertices' order, the same on any number of ranks), the
displacement there (metres, the scene's frame), the time, and after a resection the tissue
indicator per cell. outputs/run_folder.py reads it back without DOLFINx."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .vertices import GlobalVertices

NAME = "last_state.npz"


class LastStateWriter:
    def __init__(self, folder: Path, mesh, tissue=None):
        """tissue: the DG0 indicator of the cells still present (a resection), or None."""
        self.path = Path(folder) / NAME
        self.vertices = GlobalVertices(mesh)
        self.comm = mesh.comm
        self.tissue = tissue

    def write(self, t: float, u) -> None:
        """Collective: every rank calls it at each output time."""
        displacement = self.vertices.values(u)
        tissue = self.vertices.cell_values(self.tissue) if self.tissue is not None else None
        if self.comm.rank == 0:
            arrays = {
                "time": np.float64(t),
                "points": self.vertices.points,
                "tetrahedra": self.vertices.tetrahedra,
                "displacement": displacement,
            }
            if tissue is not None:
                arrays["tissue"] = tissue
            write_atomically(self.path, arrays)


def write_atomically(path: Path, arrays: dict) -> None:
    """The arrays as one .npz: written to a temporary name, synced, renamed over ``path``, and
    the folder synced, so a kill or a power cut at any moment leaves the old file or the new."""
    tmp = path.with_name(f".tmp-{path.name}")
    try:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:  # (a full disk: no mesh-sized temporary file left behind)
        tmp.unlink(missing_ok=True)
        raise
    folder = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(folder)
    finally:
        os.close(folder)
