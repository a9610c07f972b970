"""Run time against error on the cube and the brain, results in benchmarks/results/.

    .venv/bin/python benchmarks/time_vs_error.py            # both scenes, full sweeps
    .venv/bin/python benchmarks/time_vs_error.py --quick    # coarse, about a minute each

The same sweep as `brainshift bench --scene cube|brain` (fenics_brainshift/bench/sweep.py).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fenics_brainshift import logs
from fenics_brainshift.bench import run_sweep

ROOT = Path(__file__).resolve().parent.parent

if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--scenes", nargs="+", default=["cube", "brain"], choices=["cube", "brain"])
    p.add_argument("--only", action="append", metavar="NAME", help="run only this configuration; merge its row")
    args = p.parse_args()
    logs.configure("INFO")
    for scene in args.scenes:
        run_sweep(scene, "quick" if args.quick else "full", ROOT / "benchmarks" / "results", only=args.only)
    sys.exit(0)
