"""The machine's facts that `brainshift info` prints: the stack's versions, MPI, MUMPS, the BLAS
this process loaded, which optional packages are present."""

from __future__ import annotations

from .version import __version__


def versions() -> dict:
    """What `brainshift info` prints: the stack's versions, MPI, MUMPS, BLAS, the extras."""
    import dolfinx
    from mpi4py import MPI
    from petsc4py import PETSc

    return {
        "fenics_brainshift": __version__,
        "dolfinx": dolfinx.__version__,
        "petsc": ".".join(map(str, PETSc.Sys.getVersion())),
        "scalar_type": str(PETSc.ScalarType.__name__),
        "mpi": MPI.Get_library_version().splitlines()[0].strip(),
        "ranks": MPI.COMM_WORLD.size,
        "mumps": bool(PETSc.Sys.hasExternalPackage("mumps")),
        "blas": blas(),
        **{
            f"extra {name}": version_of(name) for name in ("pyvista", "tqdm", "nibabel", "matplotlib", "gmsh", "meshio")
        },
    }


def version_of(module: str) -> str:
    import importlib

    try:
        return str(getattr(importlib.import_module(module), "__version__", "present"))
    except ImportError:
        return "absent"


def blas() -> str:
    """Which BLAS library this process loaded (Debian's alternatives pick it), from the
    process's memory map: no architecture-specific path assumed."""
    import os

    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if "blas" in line.rsplit("/", 1)[-1]}
    except OSError:
        return "unknown"
    return ", ".join(sorted(os.path.relpath(os.path.realpath(p), "/usr/lib") for p in paths)) or "none loaded"
