"""A patient at clinical resolution, end to end: `brainshift prepare --voxel V` of a real scan,
`brainshift run` of the scene it writes (the settled state after the drain), and
`brainshift atlas` of it, with each command's wall time and peak memory.

At the first voxel size the atlas is the whole default one under `mpirun -n RANKS`; at the
others (where the whole atlas takes a day on this machine: resolution.md) one pose's chain of
--levels levels about the scene's drained level, with the swelling mode, on one rank: enough
to show what a rank holds at that size. Each command its own process (its children's largest
resident set, as resolution.py measures it). Writes benchmarks/results/patient_resolution.md
and .json.

    python benchmarks/patient_resolution.py --scan SCAN [--case NAME] [--voxels 3,2] [--ranks 2] [--levels 2]

--report writes the .md again from the .json. SCAN: a DICOM folder or image that prepare takes
(the results file names it; the scans are public and not shipped: benchmarks/prepare_cases.py
lists where they are).
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from resolution import measure  # noqa: E402

from fenics_brainshift.bench import machine_line  # noqa: E402

CLI = [sys.executable, "-m", "fenics_brainshift.cli", "--no-progress"]


def drained_level(scene: Path) -> float:
    """The scene's last level (m): the drained state its atlas is about."""
    match = re.search(r"^level = \[(.*)\]\s*$", scene.read_text(), flags=re.M)
    return float(re.findall(r"[-+0-9.eE]+", match.group(1))[-1])


def report(rows: list[dict], args) -> None:
    """patient_resolution.md from the rows."""
    lines = [
        "# A patient at clinical resolution: prepare, run and atlas\n",
        f"{machine_line()}; `python benchmarks/patient_resolution.py --scan SCAN --case {rows[0]['case']} --voxels "
        f"{args.voxels} --ranks {args.ranks} --levels {args.levels}`; each command its own process, its wall time "
        "and the largest resident memory of its processes (getrusage of the children: with mpirun, the largest "
        "rank's); atlas.json: the `peak_memory_mb_a_rank` the atlas reports of itself. run: the scene prepare "
        "writes, its settled state after the drain.\n",
        "| case | voxel mm | nodes | dofs | prepare s | prepare peak MB | run s (setup) | run peak MB | largest "
        "shift mm | atlas | modes | atlas s | atlas peak MB | atlas.json's peak MB | atlas.h5 MB |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['voxel_mm']:g} | {r['nodes']:,} | {r['dofs']:,} | {r['prepare_s']:.0f} | "
            f"{r['prepare_peak_mb']:.0f} | {r['run_s']:.0f} ({r['run_setup_s']:.0f}) | {r['run_peak_mb']:.0f} | "
            f"{r['largest_shift_mm']:.2f} | {r['atlas']} | {r['atlas_modes']} | {r['atlas_s']:.0f} | "
            f"{r['atlas_peak_mb']:.0f} | {r['atlas_peak_mb_a_rank']} | {r['atlas_h5_mb']:.0f} |"
        )
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scan", type=Path)
    parser.add_argument("--case", default=None, help="its name in the results (default: the scan's name)")
    parser.add_argument("--voxels", default="3,2", help="mm, comma-separated; the first gets the whole atlas")
    parser.add_argument("--ranks", type=int, default=2, help="ranks of the whole atlas")
    parser.add_argument("--levels", type=int, default=2, help="levels of the chain at the other voxel sizes")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "patient_resolution")
    parser.add_argument("--report", action="store_true", help="write the .md again from the .json, no commands")
    args = parser.parse_args()
    if args.report:
        report(json.loads(args.out.with_suffix(".json").read_text()), args)
        return
    if args.scan is None:
        parser.error("--scan is needed (or --report)")
    case = args.case or args.scan.name
    work = Path(tempfile.mkdtemp(prefix="brainshift-patient-resolution-"))
    rows = []
    for k, voxel in enumerate(float(v) for v in args.voxels.split(",")):
        folder = work / f"v{voxel:g}"
        prepared = measure([*CLI, "prepare", str(args.scan), "--voxel", f"{voxel:g}", "-o", str(folder)])
        scene = folder / "scene.toml"
        ran = measure([*CLI, "run", str(scene), "--out", str(work / f"run{voxel:g}")])
        summary = json.loads((work / f"run{voxel:g}" / "summary.json").read_text())
        atlas_out = work / f"atlas{voxel:g}"
        if k == 0:
            what = f"whole default atlas, mpirun -n {args.ranks}"
            command = ["mpirun", "-n", str(args.ranks), *CLI, "atlas", str(scene), "-o", str(atlas_out)]
        else:
            level = drained_level(scene)
            what = f"one pose, {args.levels} levels, one rank"
            vary = f"fluid.level={level - 0.005:.5f}:{level + 0.005:.5f}:{args.levels}"
            command = [*CLI, "atlas", str(scene), "-o", str(atlas_out), "--vary", vary, "--vary", "gravity.angle_z=0"]
        built = measure(command)
        info = json.loads((atlas_out / "atlas.json").read_text())
        rows.append(
            {
                "case": case,
                "voxel_mm": voxel,
                "nodes": summary["nodes"],
                "dofs": summary["dofs"],
                "prepare_s": prepared["seconds"],
                "prepare_peak_mb": prepared["peak_mb"],
                "run_s": ran["seconds"],
                "run_setup_s": summary["setup_s"],
                "run_peak_mb": ran["peak_mb"],
                "largest_shift_mm": summary["max_displacement_m"] * 1e3,
                "atlas": what,
                "atlas_modes": info["modes"],
                "atlas_s": built["seconds"],
                "atlas_peak_mb_a_rank": info.get("peak_memory_mb_a_rank"),
                "atlas_peak_mb": built["peak_mb"],
                "atlas_h5_mb": (atlas_out / "atlas.h5").stat().st_size / 2**20,
            }
        )
        print(rows[-1], flush=True)
    shutil.rmtree(work, ignore_errors=True)
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")
    report(rows, args)
    print(f"wrote {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
