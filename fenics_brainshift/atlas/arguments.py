"""The command-line arguments of `brainshift atlas` and `brainshift update` (cli.py adds them)."""
from __future__ import annotations


def add_atlas(sub) -> None:
    atlas = sub.add_parser("atlas", help="before surgery: the settled states of a scene over drain levels, head poses "
                                         "and swelling (docs/update.md)",
                           description="Solve the scene's settled states over a family of scenarios (fluid.level x "
                                       "head pose: convex weights in the update) and one perturbation per swelling "
                                       "region (bounded amplitudes); writes "
                                       "ATLAS/atlas.h5 and ATLAS/atlas.json.")
    atlas.add_argument("scene", help="scene file or bundled scene name")
    atlas.add_argument("-o", "--output", required=True, help="atlas folder")
    atlas.add_argument("--vary", action="append", default=[], metavar="KEY=VALUES",
                       help="fluid.level=0.02,0.03 or 0.01:0.05:5 (m), gravity.angle_x|y|z=-10,0,10 (degrees), "
                            "material.G=LOW,HIGH (Pa), swelling.N=LOW,HIGH (volume change of region N); default: 14 "
                            "levels x 25 poses, G from a third to three times the scene's")
    atlas.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="scene overrides")


def add_update(sub) -> None:
    update = sub.add_parser("update", help="in theatre: fit the atlas's modes to intra-operative measurements, in "
                                           "milliseconds; writes a run folder for warp",
                            description="Fit the weights of the atlas's modes to measured points (point to point: "
                                        "--pre and --target .mrk.json by label, a CSV with x_pre.. columns, an MNI "
                                        ".tag of landmark pairs; point to surface: points or a scanned surface) as "
                                        "a constrained least-squares problem; alpha by "
                                        "cross-validation. Writes OUT/displacement.xdmf (with the per-node "
                                        "uncertainty), OUT/update.json, the moved surface and markups.")
    update.add_argument("atlas", help="atlas folder (brainshift atlas SCENE -o ATLAS)")
    update.add_argument("--target", required=True, help="measured intra-operative points (mm): .mrk.json, .csv, "
                                                        ".tag or a surface (.stl, .vtk, .ply, ...)")
    update.add_argument("--pre", help="the same points before the shift (.mrk.json, matched by label)")
    update.add_argument("--frame", type=str.upper, choices=["RAS", "LPS"], default=None,
                        help="frame of a CSV or an untagged surface target (default RAS)")
    update.add_argument("--noise", type=float, default=None,
                        help="measurement noise of a point, mm per coordinate (default 1, a tracked pointer's; "
                             "the report says which was used)")
    update.add_argument("--bootstrap", type=int, default=0,
                        help="the uncertainty from this many resamplings of the points (a refit each) instead of "
                             "the weights' posterior (default: 0, the posterior, in closed form)")
    update.add_argument("--keep-all", action="store_true",
                        help="fit every point: none set aside as an outlier (by default a point whose "
                             "left-out error is far past the noise and the others' is set aside and reported)")
    update.add_argument("--image", help="a volume (.nii.gz, .nrrd) on whose grid to write OUT/uncertainty.nii.gz")
    update.add_argument("--out", default="out_update", help="output folder")
    update.add_argument("--replace", action="store_true",
                        help="replace an earlier update in --out (refused otherwise: keep each update in its own "
                             "folder, the record of what guided the operation)")
