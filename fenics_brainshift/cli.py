"""The ``brainshift`` command. ``main(argv) -> int``; tests call it directly."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import __version__


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="brainshift",
        description="Predict brain shift (or any soft body sagging as its supporting fluid drains) with DOLFINx.",
        formatter_class=_Defaults)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"],
                        help="how much to say (rank 0 only)")
    parser.add_argument("--log-all-ranks", action="store_true", help="let every MPI rank log")
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress bar (it shows on rank 0 only when stderr is a terminal)")
    sub = parser.add_subparsers(dest="command", required=True)
    from .atlas.arguments import add_atlas, add_update
    from .patients.arguments import add_prepare

    for add in (_add_run, add_prepare, _add_mesh, _add_warp, _add_fit, add_atlas, add_update, _add_compare, _add_bench):
        add(sub)
    sub.add_parser("info", help="versions of DOLFINx, PETSc, MPI, the scalar type and optional extras")
    sub.add_parser("scenes", help="the bundled scenes (run one by name: brainshift run cube)")
    return parser


def _add_run(sub) -> None:
    run = sub.add_parser("run", help="run a scene file (also under mpirun -n N)",
                         formatter_class=_Defaults)
    run.add_argument("scene", help="scene TOML file, or a bundled scene by name (brainshift scenes)")
    run.add_argument("--out", help="output folder (default: the scene's [output] folder)")
    run.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                     help="override a scene value, e.g. --set time.end=2 --set solver.kind=cholesky "
                          "(repeatable; arrays by index: fixed.0.where='z < 0.01')")
    run.add_argument("--pictures", action="store_true",
                     help="also write deformed.png and probes.png (same as --set output.pictures=true)")


def _add_mesh(sub) -> None:
    mesh = sub.add_parser("mesh", help="voxel-mesh a segmentation (label volume or surface) to XDMF",
                          description="The paper's embedding mesher: voxels of SIZE over the object's bounding "
                                      "box, those the object fills kept, floating parts dropped, five "
                                      "conforming tetrahedra per voxel. Output in metres.",
                          formatter_class=_Defaults)
    mesh.add_argument("input", help="label volume (.nii, .nii.gz, .nrrd, .seg.nrrd) or surface (.stl, .obj, .ply, "
                                    ".vtk, .vtp, .gii)")
    mesh.add_argument("--voxel", type=float, default=5.0, help="voxel size, in the input's units")
    mesh.add_argument("--scale", type=float, default=1e-3, help="input units to metres (1e-3: input in mm)")
    mesh.add_argument("--fill", type=float, default=0.5,
                      help="keep voxels the object fills at least this much (0: any it touches, the paper's rule)")
    mesh.add_argument("--parts", type=int, default=1, help="keep this many largest face-connected parts")
    mesh.add_argument("--labels", nargs="+", help="labels of a label volume to mesh, as values or a .seg.nrrd's "
                                                 "segment names (default: all > 0; a .seg.nrrd of several segments "
                                                 "must name them)")
    mesh.add_argument("-o", "--output", default="mesh.xdmf", help="output XDMF file")


def _add_warp(sub) -> None:
    warp = sub.add_parser("warp", help="the predicted intra-operative image: warp a pre-operative volume by a run",
                          description="Every voxel y of the output (the input's grid, affine and header) takes the "
                                      "input's value at the pre-operative point x with x + u(x) = y, u the run's "
                                      "last displacement (exact inversion of the P1 field); outside the brain the "
                                      "shift blends to zero over --blend mm. Optionally the same map as an ITK "
                                      "displacement-field transform for 3D Slicer (docs/slicer.md).",
                          formatter_class=_Defaults)
    warp.add_argument("run_dir", metavar="RUN_DIR", help="a run's output folder (its displacement.xdmf)")
    warp.add_argument("--image", required=True, help="pre-operative volume (.nii, .nii.gz, .nrrd, a .seg.nrrd without "
                                                     "overlapping segments), "
                                                     "in the frame of the run's mesh (mm)")
    warp.add_argument("-o", "--output", required=True, help="warped volume (.nii.gz or .nrrd)")
    warp.add_argument("--labels", action="store_true", help="a label volume: nearest voxel, labels stay labels "
                                                            "(default: linear interpolation of intensities)")
    warp.add_argument("--transform", help="also write the map as an ITK transform file (.h5) 3D Slicer loads")
    warp.add_argument("--transform-float32", action="store_true",
                      help="store the transform's values in single precision: half the file, 1e-7 relative")
    warp.add_argument("--blend", type=float, default=10.0, help="mm over which the shift fades outside the brain")
    warp.add_argument("--mesh-frame", choices=["RAS", "LPS"], default="RAS",
                      help="the frame of the run's mesh coordinates (RAS: meshes from NIfTI, this project's)")


def _add_fit(sub) -> None:
    fit = sub.add_parser("fit", help="calibrate: fit the CSF level, G and the head pose to intra-operative points",
                         description="Robust least squares of the measured points against the scene's settled state "
                                     "after the drain (point to point with --pre, else point to the predicted "
                                     "surface); one factorisation for every evaluation. Writes OUT/fitted.toml, "
                                     "OUT/fit.json (values, uncertainties, residuals) and the fitted scene's run.",
                         formatter_class=_Defaults)
    fit.add_argument("scene", help="scene file or bundled scene name")
    fit.add_argument("--target", required=True, help="measured intra-operative points (mm): .mrk.json, .csv or a "
                                                     "surface (.vtk, .stl, ...)")
    fit.add_argument("--pre", help="the same points before the shift (.mrk.json, matched by label): point to point")
    fit.add_argument("--params", required=True, help="comma-separated: fluid.level, material.G, gravity.angle_x, "
                                                     "gravity.angle_y, gravity.angle_z")
    fit.add_argument("--frame", type=str.upper, choices=["RAS", "LPS"], default=None,
                     help="the frame of a CSV target and of a surface target whose header does not say (Slicer "
                          "writes SPACE= in it); default RAS. Markups files carry their own")
    fit.add_argument("--noise", type=float, default=1.0, help="measurement noise (mm): the robust loss's scale")
    fit.add_argument("--out", default="out_fit", help="output folder")
    fit.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="scene overrides")
    fit.add_argument("--no-run", action="store_true", help="fit only; do not run the fitted scene")


class _Defaults(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults in the help where they say something: not for flags (False) or options with
    none, nor twice where the help names its own."""

    def _get_help_string(self, action):
        text = action.help or ""
        if action.default in (None, False, argparse.SUPPRESS) or "default" in text:
            return text
        return super()._get_help_string(action)


def _add_compare(sub) -> None:
    cmp = sub.add_parser("compare", help="the paper's error measures: PRE, INTRA (measured) and SIM surfaces",
                         description="Landmarks A (farthest along --up) and B (farthest along --second) with "
                                     "their 5 mm regions, d_MRI, d_MRI_bar, d_Sim and Error % (eqs. 22-25), and "
                                     "the surface error along --up over a rectangular ROI (section IV-D). SIM must be "
                                     "PRE moved by the simulation (a run's surface_final.vtk).",
                         formatter_class=_Defaults)
    cmp.add_argument("pre")
    cmp.add_argument("intra")
    cmp.add_argument("sim")
    cmp.add_argument("--scales", type=float, nargs=3, default=[1e-3, 1e-3, 1.0], metavar=("PRE", "INTRA", "SIM"),
                     help="file units to metres (medical surfaces in mm; brainshift writes metres)")
    cmp.add_argument("--up", type=float, nargs=3, default=[0.0, 1.0, 0.0], help="node A's direction (up; supine RAS: +y)")
    cmp.add_argument("--second", type=float, nargs=3, default=[0.0, 0.0, 1.0], help="node B's direction")
    cmp.add_argument("--radius", type=float, default=5.0, help="region radius, mm")
    cmp.add_argument("--depth", type=float, default=5.0, help="region depth, mm")
    cmp.add_argument("--search", type=float, default=10.0, help="lateral search radius for the INTRA landmark, mm")
    cmp.add_argument("--roi", type=float, nargs=4, metavar=("A0", "A1", "B0", "B1"),
                     help="surface-error rectangle on the two axes other than --up's, mm")
    cmp.add_argument("--spacing", type=float, default=1.0, help="surface-error grid spacing, mm")
    cmp.add_argument("-o", "--output", default="compare.json", help="JSON result (a PNG of the surface error beside it)")


def _add_bench(sub) -> None:
    bench = sub.add_parser("bench", help="run time against error: a sweep of configurations, Pareto front",
                           description="Every configuration computes the final shift of the scene; its run time "
                                       "(scene to answer) and its error against a fine P2 reference at fixed "
                                       "sample points go to DIR/time_vs_error_SCENE.csv, .md and .png, with the "
                                       "paper-equivalent configuration and a naive loop as baselines in the same run.",
                           formatter_class=_Defaults)
    bench.add_argument("--scene", choices=["cube", "brain"], default="cube",
                       help="the gelatin cube at 10 ml, or the bundled brain after the CSF has drained")
    size = bench.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="coarser meshes and fewer configurations (cube: about a minute; brain: about 11 min, mostly the paper-equivalent CG)")
    size.add_argument("--smoke", action="store_true", help="tiny meshes: a few seconds, to check that the sweep runs")
    bench.add_argument("--out", default="bench_results", help="output folder")
    bench.add_argument("--only", action="append", metavar="NAME",
                       help="run only this configuration (repeatable) and merge its row into the table already "
                            "in --out, keeping the other rows as measured")


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from mpi4py import MPI

    from . import logs
    from .errors import InputError, Interrupted, SolverError, write_failed

    logs.configure(args.log_level, args.log_all_ranks)
    if args.no_progress:
        from .outputs import progress

        progress.ENABLED = False
    comm = MPI.COMM_WORLD
    commands = {"info": _info_command, "scenes": _scenes, "mesh": _mesh, "compare": _compare, "bench": _bench,
                "run": _run, "prepare": _prepare, "warp": _warp, "fit": _fit, "atlas": _atlas, "update": _update}
    try:
        _check_finite(args)
        return commands[args.command](args, comm)
    except InputError as exc:  # bad input: nothing was written
        if comm.rank == 0:
            print(f"brainshift: error: {exc}", file=sys.stderr)
        return 2
    except Interrupted as exc:  # Ctrl-C during the run: its last good state was written
        if comm.rank == 0:
            print(f"brainshift: {exc}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:  # Ctrl-C before or after the run's loop
        if comm.rank == 0:
            print("brainshift: interrupted (Ctrl-C)", file=sys.stderr)
        return 130
    except SolverError as exc:  # the run stopped: the last good state was written
        if comm.rank == 0:
            print(f"brainshift: stopped: {exc}", file=sys.stderr)
        return 3
    except (OSError, RuntimeError) as exc:  # a file that could not be written mid-way: a full disk, a quota
        if not write_failed(exc):
            raise
        if comm.rank == 0:
            if isinstance(exc, OSError):
                what = f"{exc.strerror or exc}" + (f" '{exc.filename}'" if exc.filename else "")
            else:  # (a C++ writer's message: its first line says which file)
                what = f"a file could not be written ({str(exc).strip().splitlines()[0][:200]})"
            note = (" (a run's summary.json says \"running\", not \"ok\": its files are incomplete)"
                    if args.command in ("run", "fit", "update") else "")
            print(f"brainshift: error: {what}: free space or choose another folder{note}", file=sys.stderr)
        if comm.size > 1:  # a write fails on the rank that writes: the others wait in its barrier
            sys.stderr.flush()
            comm.Abort(1)
        return 1


def _check_finite(args) -> None:
    """Every number given on the command line is finite: argparse's float() takes "nan" and
    "inf", which then ran on (compare wrote NaN into its JSON) or named the wrong fix."""
    import math

    from .errors import InputError

    for key, value in vars(args).items():
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(v, float) and not math.isfinite(v):
                raise InputError(f"--{key.replace('_', '-')}: {v} is not a finite number")


def _run(args, comm) -> int:
    from .runner import run
    from .scene import load_scene

    scene = load_scene(args.scene, args.set + (["output.pictures=true"] if args.pictures else []))
    out = args.out or scene.output.folder
    keep = [Path(args.scene)] if Path(args.scene).is_file() else []  # (a fit's fitted.toml, run where it was fitted)
    result = run(scene, out, comm, keep=keep)
    if comm.rank == 0:
        summary = result.summary
        probes = ", ".join(f"{k}=[{', '.join(f'{c * 1e3:.3f}' for c in v)}] mm" for k, v in summary["probes"].items())
        print(f"{scene.name}: max |u| = {summary['max_displacement_m'] * 1e3:.3f} mm"
              + (f"; {probes}" if probes else "") + f"; wrote {out}/summary.json")
    return 0


def _info_command(args, comm) -> int:
    from .machine import versions

    if comm.rank == 0:
        for key, value in versions().items():
            print(f"{key:18s} {value}")
    return 0


def _scenes(args, comm) -> int:
    from .data import scene_path, scene_names

    if comm.rank == 0:
        for name in scene_names():
            print(f"{name:10s} {scene_path(name)}")
    return 0


def _bench(args, comm) -> int:
    from .bench import sweep
    from .errors import InputError
    from .outputs.files import check_writable
    from .outputs.progress import progress

    if comm.size > 1:
        raise InputError("bench: run it on one rank (it compares configurations; "
                         "benchmarks/cube_sizes.py measures ranks)")
    out = Path(args.out)
    check_writable(out, comm)
    level = "smoke" if args.smoke else "quick" if args.quick else "full"
    rows = sweep(args.scene, level, out, progress, args.only)
    best = min(rows, key=lambda r: r["max_error_mm"])
    print(f"bench {args.scene}: {len(rows)} configurations; most accurate {best['config']} "
          f"({best['max_error_mm']:.3f} mm, {best['total_s']:.2f} s); wrote {out}/time_vs_error_{args.scene}.md, "
          f".csv and .png")
    return 0


def _compare(args, comm) -> int:
    from .outputs.compare_command import compare_command

    return _report(compare_command(args, comm), comm)


def _warp(args, comm) -> int:
    from .images.command import warp_command

    return _report(warp_command(args, comm), comm)


def _fit(args, comm) -> int:
    from .fit.command import fit_command

    return _report(fit_command(args, comm), comm)


def _prepare(args, comm) -> int:
    from .errors import InputError
    from .patients.command import prepare_command

    if comm.size > 1:  # registration is threaded, not MPI-parallel: one rank does it all
        raise InputError("prepare runs on one process (SimpleITK uses the cores by threads); run it without mpirun, "
                         "then `mpirun -n N brainshift run PATIENT/scene.toml`")
    return prepare_command(args)


def _atlas(args, comm) -> int:
    from .atlas.build import atlas_command

    return _report(atlas_command(args, comm), comm)


def _update(args, comm) -> int:
    from .atlas.update_command import update_command

    return _report(update_command(args, comm), comm)


def _report(lines: list[str], comm) -> int:
    """A command's result lines, on rank 0."""
    if comm.rank == 0:
        print("\n".join(lines))
    return 0


def _mesh(args, comm) -> int:
    from . import formats
    from .errors import InputError
    from .meshing import write_voxel_mesh
    from .outputs.files import check_writable

    if not Path(args.input).is_file():
        raise InputError(f"mesh: input '{args.input}' not found")
    if not formats.is_voxelizable(args.input):
        raise InputError(f"mesh: input '{Path(args.input).name}': use a label volume (.nii, .nii.gz, .nrrd) or a surface "
                         f"(.stl, .obj, .ply, .vtk, .vtp, .gii)")
    if args.voxel <= 0 or args.scale <= 0:
        raise InputError(f"mesh: --voxel and --scale must be > 0 (got {args.voxel:g}, {args.scale:g})")
    if not 0.0 <= args.fill <= 1.0:
        raise InputError(f"mesh: --fill must be in [0, 1] (got {args.fill:g}); 0 keeps every voxel the object touches")
    if args.parts < 1:
        raise InputError(f"mesh: --parts must be >= 1 (got {args.parts})")
    output = Path(args.output)
    if output.suffix != ".xdmf":
        raise InputError(f"mesh: -o '{output}' must end in .xdmf")
    check_writable(output.parent, comm, "folder of -o", "-o")
    report = write_voxel_mesh(output, comm, args.input, args.voxel * args.scale, args.scale,
                              args.fill, args.parts, args.labels)
    if comm.rank == 0:
        print(f"{args.input}: {report}; wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
