"""`brainshift update`'s folder: displacement.xdmf (with the uncertainty; after a resection
every cell, the removed ones marked), the moved surface, probes and points, and with --image
uncertainty.nii.gz and update.png."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from .prepared import locator
from .stages import present_in


def write_outputs(out: Path, atlas, target, result, image, spread_image, whole=None) -> None:
    """OUT's files; whole: the mesh's every cell when the atlas is a resection stage's."""
    import meshio

    from ..images.frames import write_markups
    from ..surfaces.files import write_slicer_stl

    u, spread = result.displacement, result.spread
    # meshio writes the .h5 into the working directory, named after the .xdmf: written as
    # hidden files from inside OUT, then the .h5 and the .xdmf (pointing at it) renamed in
    here = os.getcwd()
    os.chdir(out)
    try:
        cells, cell_data = atlas.tetrahedra, {}
        if whole is not None:  # a resection stage: every cell, the removed ones marked (as a run's)
            cells, cell_data = whole, {"tissue": [present_in(whole, atlas.tetrahedra).astype(float)]}
        with meshio.xdmf.TimeSeriesWriter(".displacement.xdmf") as writer:
            writer.write_points_cells(atlas.points, [("tetra", cells)])
            writer.write_data(0.0, point_data={"displacement": u, "uncertainty": spread}, cell_data=cell_data)
        text = Path(".displacement.xdmf").read_text().replace(".displacement.h5", "displacement.h5")
        os.replace(".displacement.h5", "displacement.h5")
        Path(".displacement.xdmf").write_text(text)
        os.replace(".displacement.xdmf", "displacement.xdmf")
    finally:
        os.chdir(here)
    if atlas.surface_points is not None:
        moved = atlas.surface_points + result.surface_displacement
        meshio.Mesh(
            moved, [("triangle", atlas.surface_triangles)], point_data={"displacement": result.surface_displacement}
        ).write(out / "surface_final.vtk")
        write_slicer_stl(out / "surface_final.stl", moved * 1e3, atlas.surface_triangles)
    probes = atlas.info.get("probes") or {}
    if probes:
        names = list(probes)
        points = np.array([probes[k] for k in names])
        index, weight, _ = locator(atlas).weights(points)
        moved = points + np.einsum("nj,njd->nd", weight, u[index])
        write_markups(out / "probes_final.mrk.json", names, moved * 1e3)
    pairs = target.pairs
    if len(pairs):  # the pre-operative points where the update puts them (points to the surface have none)
        pre = target.pre[pairs]
        index, weight, _ = locator(atlas).weights(pre)
        write_markups(
            out / "targets_updated.mrk.json",
            [target.labels[i] for i in pairs],
            (pre + np.einsum("nj,njd->nd", weight, u[index])) * 1e3,
        )
    if image is not None:
        from ..images.volumes import write_like
        from .update_picture import write_update_picture

        write_like(
            image,
            spread_image,
            out / "uncertainty.nii.gz",
            f"uncertainty of the updated shift, mm ({result.spread_from} RMS spread)",
        )
        write_update_picture(out / "update.png", image, atlas, target, result)


def uncertainty_grid(atlas, spread: np.ndarray, image) -> np.ndarray:
    """The per-node spread (mm) interpolated on the image's grid inside the pre-operative
    brain (0 outside), for a NIfTI beside the image (Slicer)."""
    from ..images.rasterize import rasterize

    X = image.ras_to_index(atlas.points * 1e3)
    voxel, tet, lam = rasterize(X, atlas.tetrahedra, image.data.shape)
    if not len(voxel):
        raise InputError("update: --image does not overlap the atlas's brain (is it the scene's image, RAS mm?)")
    data = np.zeros(image.data.shape, dtype=np.float32)
    data.reshape(-1)[voxel] = np.einsum("ni,ni->n", lam, spread[atlas.tetrahedra[tet]]) * 1e3
    return data
