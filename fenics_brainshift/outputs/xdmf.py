"""The XDMF time series of a run, for ParaView and meshio.

DOLFINx writes XDMF for functions of the mesh's own degree, so P2 fields are written through
their P1 interpolant at the vertices; von Mises stress is cell-wise (DG0), of the run's own
material: the small-strain stress of a linear run, the Cauchy stress of a hyperelastic one,
with the tissue's coefficients (zero in removed cells) after a resection.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from dolfinx import fem
from dolfinx.io import XDMFFile

from .. import compat
from .last_state import LastStateWriter


class FieldWriter:
    """displacement.xdmf (+ .h5) with the requested fields at each output time, the latest
    state alone in last_state.npz (readable after a kill), and the deformed fine surface
    (surface_NNNN.vtk/.stl, the last also as surface_final) when the scene has one."""

    def __init__(
        self, folder: Path, mesh, V, fields: tuple[str, ...], material=None, embedding=None, tissue=None, contact=None
    ):
        """material: what gives the stress, an object with von_mises(u) (physics/material.py;
        Model.constitutive); needed when fields has "von_mises"."""
        self.fields = fields
        self.tissue = tissue  # DG0 1/0 after a resection: threshold on it in ParaView
        self.folder = folder
        self.embedding = embedding
        self.count = 0
        self.last_time: float | None = None
        self.comm = mesh.comm
        self.path = folder / "displacement.xdmf"
        self.file = XDMFFile(mesh.comm, str(self.path), "w")
        self.file.write_mesh(mesh)
        self.last_state = LastStateWriter(folder, mesh, tissue)  # what a kill leaves readable
        self.P1 = compat.vector_space(mesh, 1)
        self.out = {name: fem.Function(self.P1, name=name) for name in ("displacement", "velocity") if name in fields}
        self._u = fem.Function(V)
        self.contact = contact  # a SkullContact: its pressure is written too
        if contact is not None:
            S, self._to_block = V.sub(0).collapse()  # a scalar space numbered like V's blocks
            self._to_block = np.asarray(self._to_block) // 3
            self._pressure = fem.Function(S)
            self.contact_pressure = fem.Function(compat.scalar_space(mesh, "Lagrange", 1), name="contact_pressure")
        if "von_mises" in fields:
            DG0 = compat.scalar_space(mesh, "DG", 0)
            self.von_mises = fem.Function(DG0, name="von_mises")
            self._vm_expr = compat.expression(material.von_mises(self._u), DG0)

    def write(self, t: float, u, v) -> None:
        for name, src in (("displacement", u), ("velocity", v)):
            if name in self.out:
                self.out[name].interpolate(src)
                self.file.write_function(self.out[name], t)
        if "von_mises" in self.fields:
            self._u.x.array[:] = u.x.array
            self.von_mises.interpolate(self._vm_expr)
            self.file.write_function(self.von_mises, t)
        if self.tissue is not None:
            self.file.write_function(self.tissue, t)
        if self.contact is not None:
            owned = self.contact.nodal_pressure(u)
            n = len(self._pressure.x.array)
            blocks = self._to_block[:n]
            self._pressure.x.array[:] = np.where(blocks < len(owned), owned[np.minimum(blocks, len(owned) - 1)], 0.0)
            self._pressure.x.scatter_forward()
            self.contact_pressure.interpolate(self._pressure)
            self.file.write_function(self.contact_pressure, t)
        if self.embedding is not None:
            self.embedding.write(self.folder, f"surface_{self.count:04d}", u)
        self.last_state.write(t, u)
        self.count += 1
        self.last_time = t
        self._last_u = u

    def close(self) -> None:
        self.file.close()
        if self.embedding is not None and self.count:
            self.embedding.write(self.folder, "surface_final", self._last_u)
        if self.comm.rank == 0:
            merge_time_series(self.path)
        self.comm.barrier()


def merge_time_series(path: Path) -> None:
    """Put every field of a time step into one grid.

    DOLFINx writes one temporal collection per field; ParaView reads that, but meshio's
    TimeSeriesReader sees only one collection. One collection whose grids carry all the
    step's attributes reads in both (and in anything else that speaks XDMF 3)."""
    import xml.etree.ElementTree as ET

    ET.register_namespace("xi", "http://www.w3.org/2001/XInclude")
    tree = ET.parse(path)
    domain = tree.getroot().find("Domain")
    collections = [g for g in domain.findall("Grid") if g.get("GridType") == "Collection"]
    if len(collections) < 2:
        return
    merged: dict[str, ET.Element] = {}
    for collection in collections:
        for grid in collection.findall("Grid"):
            time = grid.find("Time").get("Value")
            if time not in merged:
                grid.set("Name", "fields")
                merged[time] = grid
            else:
                for attribute in grid.findall("Attribute"):
                    merged[time].append(attribute)
        domain.remove(collection)
    series = ET.SubElement(domain, "Grid", Name="fields", GridType="Collection", CollectionType="Temporal")
    series.extend(merged.values())
    tmp = path.with_suffix(".xdmf.tmp")
    tree.write(tmp, xml_declaration=True, encoding="utf-8")
    os.replace(tmp, path)
