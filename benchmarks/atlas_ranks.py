"""`brainshift atlas` on one rank and on two, side by side: two groups of one rank (the default:
each rank solves whole poses on its own model) and one group of two (--ranks-per-mode 2: the
mesh split), the wall time of each command and how far its modes are from one rank's.

Writes benchmarks/results/atlas_ranks.md. Each build is its own process (`mpirun -n 2` for two
ranks), after one unmeasured build that fills the JIT cache; the configurations alternate.

    python benchmarks/atlas_ranks.py [--repeats 3] [--default]

--default also times the default skull atlas of the 5 mm brain (351 modes) on one rank and on
two groups of one, once each (about 20 minutes on this machine).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift.atlas import store  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402

SKULL_8MM = [
    "--set", "mesh.voxel=0.008", "--set", "skull.gap=0.003",
    "--vary", "fluid.level=-0.015:0.05:6", "--vary", "gravity.angle_x=-12,0,12", "--vary", "gravity.angle_z=-12,0,12",
]  # fmt: skip
DEFAULT_5MM = ["--set", "mesh.voxel=0.005", "--set", "skull.gap=0.003"]
WAYS = {
    "1 rank": ([], []),
    "2 ranks, 2 groups of 1 (default)": (["mpirun", "-n", "2"], []),
    "2 ranks, 1 group of 2 (--ranks-per-mode 2)": (["mpirun", "-n", "2"], ["--ranks-per-mode", "2"]),
}


def build(way: str, args: list[str], out: Path) -> float:
    """The wall time (s) of one `brainshift atlas brain` command into ``out``."""
    launcher, extra = WAYS[way]
    shutil.rmtree(out, ignore_errors=True)
    cli = [sys.executable, "-m", "fenics_brainshift.cli"]
    command = [*launcher, *cli, "atlas", "brain", "-o", str(out), *args, *extra]
    env = dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    start = time.perf_counter()
    subprocess.run(command, check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def compare(args: list[str], repeats: int, work: Path, ways=tuple(WAYS), warm: bool = True) -> list[dict]:
    if warm:
        build("1 rank", args, work / "warm")  # (the JIT cache, once)
    times: dict[str, list[float]] = {way: [] for way in ways}
    for _ in range(repeats):
        for way in ways:
            times[way].append(build(way, args, _folder(work, way)))
    one = store.read(_folder(work, "1 rank"))
    rows = []
    for way in ways:
        atlas = store.read(_folder(work, way))
        info = json.loads((_folder(work, way) / "atlas.json").read_text())
        rows.append(
            {
                "way": way,
                "modes": info["modes"],
                "wall_s": statistics.median(times[way]),
                "all_s": times[way],
                "modes_s": info["modes_s"],
                "vertex_mm": 1e3 * float(np.abs(np.asarray(atlas.vertex_modes) - one.vertex_modes).max()),
                "surface_mm": 1e3 * float(np.abs(atlas.surface_modes - one.surface_modes).max()),
            }
        )
    base = rows[0]["wall_s"]
    for row in rows:
        row["ratio"] = row["wall_s"] / base
    return rows


def _folder(work: Path, way: str) -> Path:
    return work / f"way{list(WAYS).index(way)}"


def table(title: str, command: str, rows: list[dict]) -> list[str]:
    lines = [
        f"## {title}",
        "",
        f"`brainshift atlas brain {command}`",
        "",
        "| ranks | modes | wall s (median) | of one rank's | modes s (atlas.json) | modes vs one rank, mm | "
        "fine surface vs one rank, mm | each run, s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['way']} | {r['modes']} | {r['wall_s']:.1f} | **{r['ratio']:.2f}** | {r['modes_s']:.1f} | "
            f"{r['vertex_mm']:.2g} | {r['surface_mm']:.2g} | {', '.join(f'{t:.1f}' for t in r['all_s'])} |"
        )
    return lines + [""]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--default", action="store_true")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "atlas_ranks.md"))
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="atlas_ranks-"))
    lines = [
        "# The atlas on one rank and on two",
        "",
        f"{machine_line()}; `python benchmarks/atlas_ranks.py --repeats {args.repeats}"
        f"{' --default' if args.default else ''}`. Each build is its own process (`mpirun -n 2` for two ranks; "
        "the wall time includes starting Python and meshing), the three ways alternating, after one unmeasured "
        "build for the JIT cache. The modes are stored in single precision: a difference below 1e-6 mm is that "
        "rounding.",
        "",
    ]
    rows = compare(SKULL_8MM, args.repeats, work / "8mm")
    lines += table("The 8 mm brain's 55-mode skull atlas", " ".join(SKULL_8MM), rows)
    if args.default:  # (the JIT cache is the 8 mm atlas's: the same forms)
        rows = compare(DEFAULT_5MM, 1, work / "5mm", ways=tuple(WAYS)[:2], warm=False)
        lines += table("The 5 mm brain's default skull atlas (once each)", " ".join(DEFAULT_5MM), rows)
    Path(args.out).write_text("\n".join(lines))
    print("\n".join(lines))
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
