"""Setup and one linear step of the 8 mm brain, to compare DOLFINx versions (Debian 12's 0.5.2,
Debian 13's 0.9.0) on one machine: run it natively and under `scripts/debian13.sh`.

Setup: mesh, forms, operators, the Cholesky factor; step: the median over the first 40
dynamic steps (the drain; follower loading off, so one solve per step). Median of 3 runs
after one warm-up (compiled forms cached). Writes benchmarks/results/versions_<version>.md.

    python benchmarks/versions.py
    scripts/debian13.sh .venv/bin/python benchmarks/versions.py
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import load_scene, logs  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.compat import DOLFINX_VERSION  # noqa: E402
from fenics_brainshift.runner import Simulation  # noqa: E402

STEPS = 40


def once() -> tuple[float, float, str]:
    scene = load_scene("brain", ["mesh.voxel=0.008", "fluid.follower=false"])
    t0 = time.perf_counter()
    sim = Simulation(scene, MPI.COMM_SELF)
    sim.setup()
    setup = time.perf_counter() - t0
    times = []
    for _ in range(STEPS):
        t0 = time.perf_counter()
        sim.step()
        times.append(time.perf_counter() - t0)
    package = sim.solves.solver.ksp.getPC().getFactorSolverType()
    sim.destroy()
    return setup, statistics.median(times), package


def main() -> None:
    logs.configure("WARNING")
    once()
    runs = [once() for _ in range(3)]
    setup = statistics.median(r[0] for r in runs)
    step = statistics.median(r[1] for r in runs)
    lines = [
        f"# Setup and step of the 8 mm brain on DOLFINx {DOLFINX_VERSION}\n",
        f"{machine_line()}; one rank; `python benchmarks/versions.py` (Debian 13: under "
        f"`scripts/debian13.sh`); median of 3 runs.\n",
        "| DOLFINx | setup (s) | linear step (ms) | factor package |",
        "|---|---:|---:|---|",
        f"| {DOLFINX_VERSION} | {setup:.3f} | {step * 1e3:.2f} | {runs[-1][2]} |",
    ]
    out = ROOT / "benchmarks" / "results" / f"versions_{DOLFINX_VERSION}.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
