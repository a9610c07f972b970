"""`brainshift prepare T1 -o PATIENT`: a patient's pre-operative scan to a scene that
`brainshift run` and `brainshift atlas` take as it is (patients/prepare.py, docs/patients.md)."""

from __future__ import annotations

from ..errors import InputError
from .help_format import Defaults


def add(sub) -> None:
    prep = sub.add_parser(
        "prepare",
        help="a patient's T1 (DICOM, NIfTI, NRRD) to a scene: brain, supports, septa, skull, gravity, CSF level",
        description="Registers the ICBM152 2009a template to the T1 (rigid, affine, B-spline; "
        "SimpleITK), carries its brain mask and the bundled brain scene's supports, "
        "septa and probes onto the patient, offsets the brain's surface to an inner "
        "skull, and writes PATIENT/scene.toml for `brainshift run` (docs/patients.md).",
        formatter_class=Defaults,
    )
    prep.add_argument("t1", metavar="T1", help="the pre-operative T1: a DICOM series folder, .nii, .nii.gz or .nrrd")
    prep.add_argument("-o", "--output", required=True, metavar="PATIENT", help="the patient's folder to write")
    prep.add_argument(
        "--tumour",
        help="a tumour segmentation on the T1's grid: a DICOM-SEG (.dcm, or a folder "
        "holding one), .nii.gz, .nrrd or .seg.nrrd",
    )
    prep.add_argument(
        "--tumour-segment",
        metavar="NAME[,NAME]",
        help="the segments of --tumour that are the tumour (names or label values); needed when "
        "the file holds more than one",
    )
    prep.add_argument(
        "--position",
        default="supine",
        help="the head on the table: supine, prone, left, right (side down), angles 'ax,ay,az' "
        "(degrees, the supine gravity turned about the head's x, y, z), or craniotomy-up (the head "
        "turned so the craniotomy is uppermost, as for a lateral or low lesion; needs --craniotomy)",
    )
    prep.add_argument(
        "--craniotomy",
        metavar="X,Y,Z|tumour",
        help="the craniotomy's centre, RAS mm as 3D Slicer shows it, or 'tumour': over the tumour "
        "(--tumour) on the brain's upper side as the head lies, or anywhere with --position "
        "craniotomy-up (default: the brain's highest point)",
    )
    prep.add_argument("--craniotomy-radius", type=float, default=25.0, help="the craniotomy's radius, mm")
    prep.add_argument("--gap", type=float, default=3.0, help="the CSF layer between brain and inner skull, mm")
    prep.add_argument("--voxel", type=float, default=5.0, help="the mesh's voxel, mm")
    prep.add_argument(
        "--contrast",
        choices=["auto", "t1", "t1c", "t2", "flair", "pd"],
        default="auto",
        help="the scan's contrast: t1 (native), t1c (post-contrast), t2, flair, pd; auto: read from "
        "the DICOM series description or the file name, and measured (prepare.json)",
    )
    prep.add_argument(
        "--force",
        action="store_true",
        help="go on when the quality gate refuses the registration (an expert's call, after looking "
        "at overview.png): the scene and prepare.json record it",
    )
    prep.add_argument(
        "--affine-only", action="store_true", help="no deformable stage (faster, a coarser brain: for a quick look)"
    )


def main(args, comm) -> list[str]:
    """Prepare the patient's folder on one process; returns the report's lines."""
    from ..patients.prepare import prepare

    if comm.size > 1:  # registration is threaded, not MPI-parallel: one rank does it all
        raise InputError(
            "prepare runs on one process (SimpleITK uses the cores by threads); run it without mpirun, "
            "then `mpirun -n N brainshift run PATIENT/scene.toml`"
        )
    return prepare(args)
