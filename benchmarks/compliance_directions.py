"""The exact contact preconditioner's compliance (linalg/compliance.py) taken along the
directions each pressed node's block needs, against every node's three coordinate directions
(as it was before): one pose's chain of levels and the swelling mode of the bundled brain with
the 3 mm gap skull, at 5 and 3 mm voxels, each way its own process, in one run.

Writes benchmarks/results/compliance_directions.md and .json.

    python benchmarks/compliance_directions.py [--voxels 0.005,0.003] [--levels 14]
    python benchmarks/compliance_directions.py --by-level 0.003 0.05   (compliance_by_level.md)

The ways: "three a node" (every pressed node's three coordinate directions, as before: the
blocks exact), "every direction" (share 0: only the directions a block has, so still exact:
a node pressed on a flat face of the voxel skull has one), the default (SHARE: a node's block
along the directions that carry more than SHARE of its stiffness), and 0.05 (a coarser cut).
Measured: atlas.json's family and prior-and-swelling seconds and the columns solved, flexible
GMRES's iterations over the atlas (counted by wrapping ExactContactSolve.__call__), and how far
each way's modes are from the three-a-node modes (mm, at the mesh's vertices).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift.bench import machine_line  # noqa: E402

WAYS = {"three a node": None, "every direction": 0.0, "default": "default", "0.05": 0.05}

# one build in its own process: the compliance's share set (or three coordinate directions a
# node, as before), GMRES's iterations counted into a side file
BUILD = """
import json, sys
import numpy as np
from fenics_brainshift.linalg import compliance
from fenics_brainshift.stepping import exact_contact
way, count_file = json.loads(sys.argv[1]), sys.argv[2]
if way is None:  # every pressed node's three coordinate directions, as before
    def cover(self, nodes, S, strong):
        new = [n for n in nodes.tolist() if n not in self._of_node]
        if new:
            self.learn(np.repeat(np.array(new, dtype=np.int64), 3), np.tile(np.eye(3), (len(new), 1)))
    compliance.Compliance._cover = cover
    compliance.WEAK = 0.0
elif way != "default":
    compliance.SHARE = float(way)
counted = [0, 0]
call = exact_contact.ExactContactSolve.__call__
def counting(self, *args, **kwargs):
    its = call(self, *args, **kwargs)
    counted[0] += 1
    counted[1] += its
    return its
exact_contact.ExactContactSolve.__call__ = counting
from fenics_brainshift import cli
try:
    cli.main(sys.argv[3:])
finally:
    open(count_file, "w").write(json.dumps({"solves": counted[0], "iterations": counted[1]}))
"""


def build(way, voxel: float, levels: int, out: Path) -> dict:
    count = out.with_suffix(".count.json")
    command = [
        sys.executable, "-c", BUILD, json.dumps(way), str(count),
        "--no-progress", "atlas", "brain", "-o", str(out), "--set", f"mesh.voxel={voxel}",
        "--set", "skull.gap=0.003", "--vary", f"fluid.level=-0.015:0.05:{levels}",
    ]  # fmt: skip
    env = dict(os.environ, OMP_NUM_THREADS="1")
    done = subprocess.run(command, capture_output=True, text=True, env=env, cwd=ROOT)
    if done.returncode != 0:
        sys.exit(f"{' '.join(command)} failed:\n{done.stderr[-3000:]}")
    info = json.loads((out / "atlas.json").read_text())
    return {**json.loads(count.read_text()), "info": info}


def modes(folder: Path) -> np.ndarray:
    from fenics_brainshift.atlas import store

    return np.asarray(store.read(folder).vertex_modes)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--voxels", default="0.005,0.003", help="m, comma-separated")
    parser.add_argument("--levels", type=int, default=14)
    parser.add_argument(
        "--by-level", nargs=2, metavar=("VOXEL", "WAY"), help="compare WAY's chain with three a node's, mode by mode"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    if args.by_level:
        by_level(float(args.by_level[0]), args.by_level[1], args.levels, args.out)
        return
    command = f"python benchmarks/compliance_directions.py --voxels {args.voxels} --levels {args.levels}"
    rows = []
    with tempfile.TemporaryDirectory(prefix="directions_") as tmp:
        work = Path(tmp)
        build("default", 0.01, 2, work / "jit")  # the JIT cache, unmeasured
        for voxel in [float(v) for v in args.voxels.split(",")]:
            reference = None
            for name, way in WAYS.items():
                out = work / f"{voxel}_{name.replace(' ', '_')}"
                result = build(way, voxel, args.levels, out)
                info = result["info"]
                here = modes(out)
                reference = here if reference is None else reference
                row = {
                    "voxel_mm": round(voxel * 1e3, 3),
                    "way": name,
                    "nodes": info["nodes"],
                    "family_modes": info["family_modes"],
                    "family_s": info["family_s"],
                    "per_level_s": info["family_s"] / info["family_modes"],
                    "prior_and_swelling_s": info["prior_and_swelling_s"],
                    "columns": info["contact_compliance"]["columns"],
                    "compliance_mb": info["contact_compliance"]["megabytes"],
                    "solves": result["solves"],
                    "gmres_iterations": result["iterations"],
                    "modes_from_three_mm": float(np.abs(here - reference).max() * 1e3),
                }
                rows.append(row)
                print(json.dumps(row), flush=True)
    write(rows, command, args.out)


def by_level(voxel: float, way: str, levels: int, folder: Path) -> None:
    """One chain built with every pressed node's three directions and one with WAY (both
    processes at once: no time is measured), compared mode by mode: where the contact states
    part. Writes compliance_by_level.md."""
    from concurrent.futures import ThreadPoolExecutor

    from fenics_brainshift.atlas import store

    with tempfile.TemporaryDirectory(prefix="directions_") as tmp:
        work = Path(tmp)
        with ThreadPoolExecutor(2) as pool:
            done = [pool.submit(build, w, voxel, levels, work / n) for w, n in ((None, "three"), (way, "way"))]
            for future in done:
                future.result()
        three, other = store.read(work / "three"), store.read(work / "way")
    lines = [
        f"# Three a node's chain against {way}'s, mode by mode",
        "",
        f"{machine_line()}; `python benchmarks/compliance_directions.py --by-level {voxel:g} {way} --levels "
        f"{levels}`. The bundled brain at {voxel * 1e3:g} mm, skull 3 mm out; one pose's chain of levels and the "
        "swelling mode, built twice; each mode's largest distance between the two (mm) and the nodes farther "
        "apart than 0.1 mm.",
        "",
        "| mode | level m | largest shift mm | apart, max mm | nodes apart > 0.1 mm |",
        "|---|---:|---:|---:|---:|",
    ]
    for k, scenario in enumerate(three.scenarios):
        apart = np.linalg.norm(three.vertex_modes[k] - other.vertex_modes[k], axis=1) * 1e3
        level = (scenario.get("values") or {}).get("fluid.level")
        lines.append(
            f"| {scenario['kind']} | {'-' if level is None else format(level, '.3f')} | "
            f"{np.linalg.norm(three.vertex_modes[k], axis=1).max() * 1e3:.2f} | {apart.max():.4f} | "
            f"{int((apart > 0.1).sum())} of {len(apart):,} |"
        )
    (folder / "compliance_by_level.md").write_text("\n".join(lines) + "\n")


def write(rows: list[dict], command: str, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "compliance_directions.json").write_text(json.dumps({"command": command, "rows": rows}, indent=1) + "\n")
    lines = [
        "# The contact preconditioner's compliance along the directions a node's block needs",
        "",
        f"{machine_line()}; `{command}`. The bundled brain, skull 3 mm out; one pose's chain of "
        "levels and the swelling mode; each way its own process, one after another in one run.",
        "",
        "| voxel mm | nodes | way | a level in the chain s | prior and swelling s | columns | G MB "
        "| solves | GMRES iterations | modes from three a node's, max mm |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['voxel_mm']:g} | {r['nodes']:,} | {r['way']} | {r['per_level_s']:.2f} | "
            f"{r['prior_and_swelling_s']:.1f} | {r['columns']:,} | {r['compliance_mb']:.1f} | {r['solves']} | "
            f"{r['gmres_iterations']} | {r['modes_from_three_mm']:.4f} |"
        )
    (folder / "compliance_directions.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
