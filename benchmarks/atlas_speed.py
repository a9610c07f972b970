"""How long `brainshift atlas` takes on the 5 mm brain with the skull: the goal's 200 modes
(8 levels as the fluid drains x 5 x 5 head poses, and the whole-brain swelling mode) and the
default atlas (14 levels x 25 poses + 1), each built by the command itself in this process.

Writes benchmarks/results/atlas_speed.md. One process, one rank.

    python benchmarks/atlas_speed.py [--voxel 0.005] [--gap 0.003] [--keep FOLDER]

--keep FOLDER: the default atlas is written to FOLDER (benchmarks/update.py --atlas reads it).
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import logs  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.commands.atlas import arguments as atlas_arguments  # noqa: E402
from fenics_brainshift.commands.atlas import main as atlas_command  # noqa: E402

ANGLES = "-12,-6,0,6,12"
ISSUE = ["fluid.level=-0.015:0.05:8", f"gravity.angle_x={ANGLES}", f"gravity.angle_z={ANGLES}"]


def timed(sets: list[str], vary: list[str], out: Path) -> dict:
    args = atlas_arguments("brain", out, vary, sets)
    start = time.perf_counter()
    atlas_command(args, MPI.COMM_WORLD)
    wall = time.perf_counter() - start
    info = json.loads((out / "atlas.json").read_text())
    return {
        "modes": info["modes"],
        "states": info["settled_states"],
        "modes_s": info["modes_s"],
        "setup_s": info["setup_s"],
        "wall_s": wall,
        "left_out": len(info["left_out"]),
        "per_mode_s": info["modes_s"] / info["modes"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--voxel", type=float, default=0.005)
    parser.add_argument("--gap", type=float, default=0.003)
    parser.add_argument("--keep", default=None)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "atlas_speed.md"))
    args = parser.parse_args()
    logs.configure("WARNING")
    sets = [f"mesh.voxel={args.voxel}", f"skull.gap={args.gap}"]
    with tempfile.TemporaryDirectory(prefix="brainshift-atlas-speed-") as tmp:
        issue = timed(sets, ISSUE, Path(tmp) / "issue")
        print(issue, flush=True)
        whole = timed(sets, [], Path(args.keep) if args.keep else Path(tmp) / "default")
        print(whole, flush=True)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    set_text = " ".join(f"--set {s}" for s in sets)
    command = f"python benchmarks/atlas_speed.py --voxel {args.voxel:g} --gap {args.gap:g}"
    rows = [("the goal's: " + " ".join(f"--vary {v}" for v in ISSUE), issue), ("the default (no --vary)", whole)]
    table = "\n".join(
        f"| {name} | {r['modes']} | {r['states']} | {r['left_out']} | {r['setup_s']:.1f} | "
        f"**{r['modes_s']:.0f}** | {r['per_mode_s']:.2f} | {r['wall_s']:.0f} |"
        for name, r in rows
    )
    met = "met" if issue["modes"] >= 200 and issue["modes_s"] <= 300 else "not met"
    text = f"""# The atlas's speed with the skull

{machine_line()}; one rank; `{command}`; each atlas built by `brainshift atlas brain {set_text}`
with the --vary shown, in one process (the first build pays the JIT cache). The goal is at
least 200 modes on the 5 mm brain, skull included, in at most 5 minutes on one core: **{met}**.

| atlas | modes | settled states | left out | setup s | modes s | s a mode | wall s (with writing) |
|---|---|---|---|---|---|---|---|
{table}

Peak memory of the process: {peak_mb:.0f} MB. What a mode costs, and why:
[skull_atlas.md](skull_atlas.md).
"""
    Path(args.out).write_text(text)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
