"""Outputs: XDMF time series for ParaView (and meshio), probe CSV, summary.json.

DOLFINx writes XDMF for functions of the mesh's own degree, so P2 fields are written through
their P1 interpolant at the vertices; von Mises stress is cell-wise (DG0).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
from dolfinx import fem
from dolfinx.io import XDMFFile

from . import compat, forms


class FieldWriter:
    """displacement.xdmf (+ .h5) with the requested fields at each output time."""

    def __init__(self, folder: Path, mesh, V, fields: tuple[str, ...], mu: float, lmbda: float):
        self.fields = fields
        self.file = XDMFFile(mesh.comm, str(folder / "displacement.xdmf"), "w")
        self.file.write_mesh(mesh)
        self.P1 = compat.vector_space(mesh, 1)
        self.out = {name: fem.Function(self.P1, name=name) for name in ("displacement", "velocity") if name in fields}
        self._u = fem.Function(V)
        if "von_mises" in fields:
            DG0 = compat.scalar_space(mesh, "DG", 0)
            self.von_mises = fem.Function(DG0, name="von_mises")
            self._vm_expr = compat.expression(forms.von_mises(self._u, mu, lmbda), DG0)

    def write(self, t: float, u, v) -> None:
        for name, src in (("displacement", u), ("velocity", v)):
            if name in self.out:
                self.out[name].interpolate(src)
                self.file.write_function(self.out[name], t)
        if "von_mises" in self.fields:
            self._u.x.array[:] = u.x.array
            self.von_mises.interpolate(self._vm_expr)
            self.file.write_function(self.von_mises, t)

    def close(self) -> None:
        self.file.close()


def write_json(path: Path, data: dict, comm) -> None:
    """Written by rank 0 via a temporary file and a rename: never half a file."""
    if comm.rank == 0:
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(data, indent=2, default=_plain) + "\n")
        os.replace(tmp, path)
    comm.barrier()


def write_csv(path: Path, header: list[str], rows: list[list[float]], comm) -> None:
    if comm.rank == 0:
        np.savetxt(path, np.array(rows, dtype=float).reshape(-1, len(header)), delimiter=",",
                   header=",".join(header), comments="", fmt="%.10g")
    comm.barrier()


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value)}")
