"""Surface files as this project reads them (their triangles, and the frame they declare) and
writes them for 3D Slicer (write_slicer_stl: a binary STL in mm, SPACE=RAS).

Triangles: GIfTI by nibabel; VTK's own formats (.vtk, .vtp, .vtu: 3D Slicer saves models as
legacy VTK polydata, which meshio cannot read) by VTK through pyvista when it is installed;
the rest (.stl, .obj, .ply, .off) by meshio. Polygons are fanned into triangles.

Frame: 3D Slicer writes ``SPACE=RAS`` or ``SPACE=LPS`` in the header of every mesh file it
saves (the 80-byte header of an STL, the title line of a VTK file, a comment of PLY and OBJ),
and since 4.11 saves models in LPS; this project's frame is RAS, so a file tagged LPS is
turned (x and y negated: a rotation by 180 degrees about z, which keeps every triangle's
orientation)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ..errors import InputError

_TAG = re.compile(rb"SPACE\s*=\s*(RAS|LPS)\b", re.IGNORECASE)
HEADER_BYTES = 4096  # the tag is in the header: before any binary data


VTK_SUFFIXES = (".vtk", ".vtp", ".vtu")


class SurfaceFileError(InputError):
    """A surface file that cannot be read as triangles (the message names the file)."""


def read_polygons(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(points as in the file, triangles) of a surface file; reader errors propagate."""
    name = path.name.lower()
    if name.endswith(".gii"):
        import nibabel as nib

        gii = nib.load(str(path))
        return gii.agg_data("pointset"), gii.agg_data("triangle")
    if name.endswith(VTK_SUFFIXES):
        try:
            import pyvista
        except ImportError:
            pyvista = None
        if pyvista is not None:
            from vtkmodules.vtkCommonCore import vtkLogger, vtkObject

            warnings = vtkObject.GetGlobalWarningDisplay()
            verbosity = vtkLogger.GetCurrentVerbosityCutoff()  # (restored as the caller had it)
            vtkObject.GlobalWarningDisplayOff()  # a damaged file: our one line, not VTK's six
            vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
            try:
                data = pyvista.read(str(path))
            finally:
                vtkObject.SetGlobalWarningDisplay(warnings)
                vtkLogger.SetStderrVerbosity(verbosity)
            if not isinstance(data, pyvista.PolyData):  # a .vtu: its boundary
                data = data.extract_surface(algorithm="dataset_surface")
            surface = data.triangulate()
            return np.asarray(surface.points), np.asarray(surface.faces).reshape(-1, 4)[:, 1:]
    import meshio

    try:
        mesh = meshio.read(str(path))
    except SystemExit:  # meshio 5.0 exits on a VTK type it does not read (POLYDATA)
        raise ValueError("meshio cannot read it (install pyvista: the viz extra reads every VTK file)") from None
    chunks = []
    for block in mesh.cells:
        if block.type == "triangle":
            chunks.append(block.data)
        elif block.type in ("quad", "polygon") or block.type.startswith("polygon"):
            d = block.data
            chunks += [d[:, [0, k, k + 1]] for k in range(1, d.shape[1] - 1)]
    return mesh.points, (np.concatenate(chunks) if chunks else np.zeros((0, 3), int))


def declared_frame(path: Path) -> str | None:
    """ "RAS", "LPS", or None when the file does not say; InputError when it says both."""
    with open(path, "rb") as f:
        head = f.read(80 if path.suffix.lower() == ".stl" else HEADER_BYTES)
    frames = {m.group(1).upper().decode() for m in _TAG.finditer(head)}
    if len(frames) > 1:
        raise InputError(f"'{path.name}' declares both SPACE=RAS and SPACE=LPS in its header; keep the one it is in")
    return frames.pop() if frames else None


def to_ras(points: np.ndarray, path: Path, frame: str | None, option: str = "--frame") -> np.ndarray:
    """The points of surface file ``path`` in RAS: in the frame its header declares, else in
    ``frame`` (None: RAS). A given ``frame`` that contradicts the header is an error."""
    declared = declared_frame(path)
    if declared is not None and frame is not None and declared != frame.upper():
        raise InputError(
            f"{option} {frame} but '{path.name}' declares SPACE={declared} in its header; drop {option} "
            f"(the file's own tag is used) or fix the file"
        )
    if (declared or frame or "RAS").upper() == "LPS":
        points = points * np.array([-1.0, -1.0, 1.0])
    return points


def read_surface(path: Path, scale: float, frame: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points (m, RAS) and triangles of a surface file, degenerate triangles dropped. The
    frame is the one the file's header declares (SPACE=LPS as 3D Slicer writes it), else
    ``frame`` (None: RAS)."""
    try:
        points, triangles = read_polygons(path)
    except SurfaceFileError:
        raise
    except Exception as exc:
        raise SurfaceFileError(f"'{path.name}' could not be read as a surface: {exc}") from None
    points = np.asarray(points, dtype=float)
    triangles = np.asarray(triangles, dtype=np.int64)
    if len(triangles) == 0 or points.size == 0:
        raise SurfaceFileError(f"'{path.name}' holds no triangles")
    points = points.reshape(len(points), -1)[:, :3]
    if not np.isfinite(points).all():
        bad = int(np.count_nonzero(~np.isfinite(points).all(axis=1)))
        raise SurfaceFileError(f"'{path.name}' has {bad} vertices that are not finite (NaN or infinite); repair it")
    points = to_ras(points * scale, path, frame)
    # bad triangles (degenerate, out-of-range indices) are dropped, not fatal
    ok = np.all((triangles >= 0) & (triangles < len(points)), axis=1)
    triangles = triangles[ok]
    p = points[triangles]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    if not np.any(area > 0):
        raise SurfaceFileError(f"'{path.name}' holds no triangle with an area (all degenerate or out of range)")
    return points, triangles[area > 0]


def write_slicer_stl(path: Path, points_mm: np.ndarray, triangles: np.ndarray) -> Path:
    """A binary STL as 3D Slicer reads it: millimetres, and the frame in its 80-byte header
    ("SPACE=RAS", as Slicer writes it: an STL without the tag is taken as LPS, which mirrored
    ours in x and y, and metres made it 1000x too small). Via a temporary file and a rename."""
    p = np.asarray(points_mm, dtype=np.float64)[np.asarray(triangles)]  # (T, 3, 3)
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    lengths = np.linalg.norm(normals, axis=1)[:, None]
    normals = np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 0)
    record = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])
    data = np.zeros(len(p), dtype=record)
    data["normal"], data["vertices"] = normals, p
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(b"fenics-brainshift output. SPACE=RAS".ljust(80, b" "))
        f.write(np.uint32(len(p)).tobytes())
        f.write(data.tobytes())
    os.replace(tmp, path)
    return path
