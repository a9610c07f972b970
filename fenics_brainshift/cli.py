"""The ``brainshift`` command. ``main(argv) -> int``; tests call it directly."""
from __future__ import annotations

import argparse
import sys

from . import __version__


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="brainshift",
        description="Predict brain shift (or any soft body sagging as its supporting fluid drains) with DOLFINx.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"],
                        help="how much to say (rank 0 only)")
    parser.add_argument("--log-all-ranks", action="store_true", help="let every MPI rank log")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a scene file (also under mpirun -n N)",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    run.add_argument("scene", help="scene TOML file")
    run.add_argument("--out", help="output folder (default: the scene's [output] folder)")
    run.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                     help="override a scene value, e.g. --set time.end=2 --set solver.kind=cholesky "
                          "(repeatable; arrays by index: fixed.0.where='z < 0.01')")
    sub.add_parser("info", help="versions of DOLFINx, PETSc, MPI and the scalar type")
    return parser


def _info() -> dict:
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
    }


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from mpi4py import MPI

    from . import logs
    from .scene import SceneError
    from .solver import SolverError

    logs.configure(args.log_level, args.log_all_ranks)
    comm = MPI.COMM_WORLD
    try:
        if args.command == "info":
            if comm.rank == 0:
                for key, value in _info().items():
                    print(f"{key:18s} {value}")
            return 0
        from .scene import load_scene
        from .simulation import run

        scene = load_scene(args.scene, args.set)
        summary = run(scene, args.out or scene.output.folder, comm)
        if comm.rank == 0:
            probes = ", ".join(f"{k}=[{', '.join(f'{c * 1e3:.3f}' for c in v)}] mm"
                               for k, v in summary["probes"].items())
            print(f"{scene.name}: max |u| = {summary['max_displacement_m'] * 1e3:.3f} mm"
                  + (f"; {probes}" if probes else "")
                  + f"; wrote {args.out or scene.output.folder}/summary.json")
        return 0
    except (SceneError, SolverError) as exc:
        if comm.rank == 0:
            print(f"brainshift: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
