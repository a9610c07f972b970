"""Volumetric locking of P1 tetrahedra as nu nears 0.5: the paper's cube's settled top
displacement with P1 against P2, in one run.

    .venv/bin/python benchmarks/locking.py   # writes benchmarks/results/locking.md

The planner warns from LOCKING_NU (runner/plan.py) on: the numbers behind that threshold.
"""

from __future__ import annotations

import platform
import sys
from pathlib import Path

import numpy as np

from fenics_brainshift import load_scene, logs, run

ROOT = Path(__file__).resolve().parents[1]
NUS = (0.45, 0.4925, 0.499, 0.4999, 0.4999999)


def top(nu: float, degree: int) -> float:
    """|u| (mm) of the cube's probe, settled."""
    scene = load_scene(
        "cube", ["time.mode=quasi-static", f"material.nu={nu}", f"element.degree={degree}", "output.pictures=false"]
    )
    summary = run(scene, None).summary
    return float(np.linalg.norm(next(iter(summary["probes"].values()))) * 1e3)


def main() -> int:
    logs.configure("ERROR")
    lines = [
        "# P1 locking: the paper's cube, settled, P1 against P2",
        "",
        f"`.venv/bin/python benchmarks/locking.py`; {platform.processor() or platform.machine()}, one rank; "
        f"the bundled cube scene's probe (|u|, mm), quasi-static.",
        "",
        "| nu | P1 (mm) | P2 (mm) | P1 / P2 |",
        "|---:|---:|---:|---:|",
    ]
    for nu in NUS:
        p1, p2 = top(nu, 1), top(nu, 2)
        lines.append(f"| {nu} | {p1:.3f} | {p2:.3f} | {p1 / p2:.3f} |")
        print(lines[-1], flush=True)
    out = ROOT / "benchmarks" / "results" / "locking.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
