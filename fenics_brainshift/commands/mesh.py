"""`brainshift mesh INPUT -o MESH.xdmf`: the paper's voxel mesher on a label volume or a surface."""

from __future__ import annotations

from pathlib import Path

from .. import formats
from ..errors import InputError
from .help_format import Defaults, add_overwrite


def add(sub) -> None:
    mesh = sub.add_parser(
        "mesh",
        help="voxel-mesh a segmentation (label volume or surface) to XDMF",
        description="The paper's embedding mesher: voxels of SIZE over the object's bounding "
        "box, those the object fills kept, floating parts dropped, five "
        "conforming tetrahedra per voxel. Output in metres.",
        formatter_class=Defaults,
    )
    mesh.add_argument(
        "input", help="label volume (.nii, .nii.gz, .nrrd, .seg.nrrd) or surface (.stl, .obj, .ply, .vtk, .vtp, .gii)"
    )
    mesh.add_argument("--voxel", type=float, default=5.0, help="voxel size, in the input's units")
    mesh.add_argument("--scale", type=float, default=1e-3, help="input units to metres (1e-3: input in mm)")
    mesh.add_argument(
        "--fill",
        type=float,
        default=0.5,
        help="keep voxels the object fills at least this much (0: any it touches, the paper's rule)",
    )
    mesh.add_argument("--parts", type=int, default=1, help="keep this many largest face-connected parts")
    mesh.add_argument(
        "--labels",
        nargs="+",
        help="labels of a label volume to mesh, as values or a .seg.nrrd's "
        "segment names (default: all > 0; a .seg.nrrd of several segments "
        "must name them)",
    )
    mesh.add_argument("-o", "--output", default="mesh.xdmf", help="output XDMF file")
    add_overwrite(mesh, "-o")


def main(args, comm) -> list[str]:
    """Check the arguments, mesh, write; returns the mesher's report."""
    from ..meshing import write_voxel_mesh
    from ..outputs.files import check_output_file, check_writable

    if not Path(args.input).is_file():
        raise InputError(f"mesh: input '{args.input}' not found")
    if not formats.is_voxelizable(args.input):
        raise InputError(
            f"mesh: input '{Path(args.input).name}': use a label volume (.nii, .nii.gz, .nrrd) or a "
            f"surface (.stl, .obj, .ply, .vtk, .vtp, .gii)"
        )
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
    for path in (output, output.with_suffix(".h5")):  # (the mesh's XDMF and its HDF5 beside it)
        check_output_file(path, "-o", "mesh", [(args.input, "INPUT")], args.overwrite)
    report = write_voxel_mesh(
        output, comm, args.input, args.voxel * args.scale, args.scale, args.fill, args.parts, args.labels
    )
    return [f"{args.input}: {report}; wrote {args.output}"]
