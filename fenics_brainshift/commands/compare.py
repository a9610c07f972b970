"""`brainshift compare PRE INTRA SIM`: the command around the paper's error measures (outputs/metrics.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import json_text
from ..errors import InputError
from ..outputs.files import check_output_file, check_writable
from ..outputs.metrics import compare
from ..surfaces.files import read_surface
from .help_format import Defaults, add_overwrite


def add(sub) -> None:
    cmp = sub.add_parser(
        "compare",
        help="the paper's error measures: PRE, INTRA (measured) and SIM surfaces",
        description="Landmarks A (farthest along --up) and B (farthest along --second) with "
        "their 5 mm regions, d_MRI, d_MRI_bar, d_Sim and Error % (eqs. 22-25), and "
        "the surface error along --up over a rectangular ROI (section IV-D). SIM must be "
        "PRE moved by the simulation (a run's surface_final.vtk).",
        formatter_class=Defaults,
    )
    cmp.add_argument("pre")
    cmp.add_argument("intra")
    cmp.add_argument("sim")
    cmp.add_argument(
        "--scales",
        type=float,
        nargs=3,
        default=[1e-3, 1e-3, 1.0],
        metavar=("PRE", "INTRA", "SIM"),
        help="file units to metres (medical surfaces in mm; brainshift writes metres)",
    )
    cmp.add_argument(
        "--up", type=float, nargs=3, default=[0.0, 1.0, 0.0], help="node A's direction (up; supine RAS: +y)"
    )
    cmp.add_argument("--second", type=float, nargs=3, default=[0.0, 0.0, 1.0], help="node B's direction")
    cmp.add_argument("--radius", type=float, default=5.0, help="region radius, mm")
    cmp.add_argument("--depth", type=float, default=5.0, help="region depth, mm")
    cmp.add_argument("--search", type=float, default=10.0, help="lateral search radius for the INTRA landmark, mm")
    cmp.add_argument(
        "--roi",
        type=float,
        nargs=4,
        metavar=("A0", "A1", "B0", "B1"),
        help="surface-error rectangle on the two axes other than --up's, mm",
    )
    cmp.add_argument("--spacing", type=float, default=1.0, help="surface-error grid spacing, mm")
    cmp.add_argument(
        "-o", "--output", default="compare.json", help="JSON result (a PNG of the surface error beside it)"
    )
    add_overwrite(cmp, "-o")


def main(args, comm) -> list[str]:
    """`brainshift compare`: rank 0 measures and writes; returns the report's lines."""
    out = Path(args.output)
    check_writable(out.parent, comm, "folder of -o", "-o")
    inputs = [(args.pre, "PRE surface"), (args.intra, "INTRA surface"), (args.sim, "SIM surface")]
    for path in (out, out.with_suffix(".png")):  # (the JSON and the picture beside it)
        check_output_file(path, "-o", "compare", inputs, args.overwrite)
    if comm.rank != 0:
        return []
    for name in (args.pre, args.intra, args.sim):
        if not Path(name).is_file():
            raise InputError(f"compare: '{name}' not found")
    if min(args.scales) <= 0 or min(args.radius, args.depth, args.search, args.spacing) <= 0:
        raise InputError("compare: --scales, --radius, --depth, --search and --spacing must be > 0")
    pre, intra, sim = (read_surface(Path(f), s)[0] for f, s in zip((args.pre, args.intra, args.sim), args.scales))
    check_scales((pre, intra, sim), args.scales)
    mm = 1e-3
    roi = ((args.roi[0] * mm, args.roi[1] * mm), (args.roi[2] * mm, args.roi[3] * mm)) if args.roi else None
    try:
        result = compare(
            pre,
            intra,
            sim,
            args.up,
            args.second,
            args.radius * mm,
            args.depth * mm,
            args.search * mm,
            roi,
            args.spacing * mm,
        )
    except InputError as exc:  # the measures' own checks: surfaces that do not match, an empty ROI
        raise InputError(f"compare: {exc}") from None
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json_text.dumps({"units": "m", **result}, indent=1) + "\n")
    lines = []
    for name in ("A", "B"):
        r = result[name]
        e = ["-" if v is None else f"{v:.0f}" for v in r["error_percent_vs_d_mri"]]
        lines.append(
            f"node {name}: d_MRI {np.round(np.array(r['d_mri']) * 1e3, 2)} mm, d_Sim "
            f"{np.round(np.array(r['d_sim']) * 1e3, 2)} mm, Error % x {e[0]}, y {e[1]}, z {e[2]}, "
            f"norm {e[3]}"
        )
    if "surface_error" in result:
        se = result["surface_error"]
        lines.append(
            f"surface error along {se['height_axis']} ({se['grid_points']} grid points): max "
            f"{se['max'] * 1e3:.2f}, min {se['min'] * 1e3:.2f}, mean {se['mean'] * 1e3:.2f}, median "
            f"{se['median'] * 1e3:.2f}, MAE {se['mae'] * 1e3:.2f} mm"
        )
        from ..outputs.pictures import surface_error_plot

        surface_error_plot(out.with_suffix(".png"), se)
    lines.append(f"wrote {out}")
    return lines


def check_scales(surfaces, scales) -> None:
    """Three surfaces of one brain are about one size: one that is 10x or 1000x the others
    has the wrong --scales entry (it used to end in "raise --search")."""
    sizes = np.array([np.linalg.norm(np.ptp(p, axis=0)) for p in surfaces])
    typical = float(np.median(sizes))
    for name, size, scale in zip(("PRE", "INTRA", "SIM"), sizes, scales):
        if not typical / 3.0 <= size <= 3.0 * typical:
            fix = scale * 10.0 ** round(float(np.log10(typical / size)))
            raise InputError(
                f"compare: {name} is {size:.3g} m across against the others' {typical:.3g} m with --scales "
                f"{' '.join(f'{v:g}' for v in scales)}: is its scale {fix:g}? (--scales: each file's unit "
                f"in metres, PRE INTRA SIM)"
            )
