"""`brainshift info`: this package's version and the stack's (DOLFINx, PETSc, MPI, extras)."""

from __future__ import annotations


def add(sub) -> None:
    sub.add_parser(
        "info", help="the versions of fenics-brainshift, DOLFINx, PETSc, MPI, the scalar type and optional extras"
    )


def main(args, comm) -> list[str]:
    """One line per version."""
    from ..machine import versions

    return [f"{key:18s} {value}" for key, value in versions().items()]
