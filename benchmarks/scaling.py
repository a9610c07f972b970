"""Per-step time against problem size with CG + GAMG (or BoomerAMG) under MPI, and peak memory.

A 2:2:1 block (the cube scene's material, gravity, fixed floor; dry, so every step is one
solve) on structured grids from about 10^4 to 10^6 dofs, a few Newmark steps each, in its own
`mpirun -n RANKS` process. Writes benchmarks/results/scaling.{csv,md,png}.

    .venv/bin/python benchmarks/scaling.py                 # 2 ranks, up to ~1e6 dofs
    .venv/bin/python benchmarks/scaling.py --max-n 54      # stop at ~3e5 dofs
    .venv/bin/python benchmarks/scaling.py --kind cg-hypre # the same with hypre's BoomerAMG
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CASE = r"""
import json, resource, statistics, sys, time
from mpi4py import MPI
from fenics_brainshift import logs
from fenics_brainshift.scene import scene_from_dict
from fenics_brainshift.runner import Simulation
logs.configure("WARNING")
n, steps, kind = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
scene = scene_from_dict({
    "mesh": {"shape": "box", "size": [0.05, 0.05, 0.025], "cells": [n, n, max(1, n // 2)]},
    "material": {"E": 729.1, "nu": 0.48, "density": 1048.0},
    "fixed": [{"where": "z < 1e-9"}],
    "time": {"mode": "dynamic", "dt": 0.05, "end": 0.05 * steps},
    "damping": {"a": 0.02, "b": 0.02},
    "solver": {"kind": kind, "rtol": 1e-8},
})
comm = MPI.COMM_WORLD
t0 = time.perf_counter()
sim = Simulation(scene, comm)
sim.setup()
sim.dynamic.check_energy = False
setup = time.perf_counter() - t0
times, its = [], []
for _ in range(steps):
    t0 = time.perf_counter(); its.append(sim.step()); times.append(time.perf_counter() - t0)
peak = comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, op=MPI.SUM)  # kB, all ranks
if comm.rank == 0:
    print(json.dumps({"n": n, "dofs": sim.model.sizes()["dofs"], "ranks": comm.size, "setup_s": setup,
                      "step_s": statistics.median(times), "iterations": statistics.median(its),
                      "peak_memory_MB": peak / 1024}))
"""


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ranks", type=int, default=2)
    p.add_argument("--steps", type=int, default=3)
    p.add_argument("--max-n", type=int, default=86)
    p.add_argument("--kind", default="cg-gamg", choices=["cg-gamg", "cg-hypre"])
    p.add_argument("--out", default=None, help="file stem (default benchmarks/results/scaling, _hypre for cg-hypre)")
    args = p.parse_args(argv)
    if args.out is None:
        args.out = str(ROOT / "benchmarks" / "results" / ("scaling" if args.kind == "cg-gamg" else "scaling_hypre"))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from cube_sizes import machine

    env = dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "case.py"
        script.write_text(CASE)
        for n in (16, 24, 36, 54, 86):
            if n > args.max_n:
                break
            cmd = [
                shutil.which("mpirun"),
                "-n",
                str(args.ranks),
                sys.executable,
                str(script),
                str(n),
                str(args.steps),
                args.kind,
            ]
            proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT)
            if proc.returncode != 0:
                print(f"n={n}: failed\n{proc.stderr[-2000:]}", file=sys.stderr)
                break
            row = json.loads(proc.stdout.strip().splitlines()[-1])
            rows.append(row)
            print(row, flush=True)
    stem = Path(args.out)
    stem.parent.mkdir(parents=True, exist_ok=True)
    with open(stem.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    title = {"cg-gamg": "CG + GAMG", "cg-hypre": "CG + BoomerAMG (hypre)"}[args.kind]
    lines = [
        f"# Per-step time against size, {title}\n",
        f"{machine()}; `python benchmarks/scaling.py --ranks {args.ranks} --kind {args.kind}`; "
        f"median of {args.steps} Newmark steps, "
        f"rtol 1e-8, nu = 0.48; peak memory summed over ranks.\n",
        "| grid n | dofs | ranks | setup (s) | step (s) | us per dof per step | CG iterations | peak memory (MB) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r['n']} | {r['dofs']} | {r['ranks']} | {r['setup_s']:.1f} | {r['step_s']:.2f} | "
        f"{r['step_s'] / r['dofs'] * 1e6:.1f} | {r['iterations']:.0f} | {r['peak_memory_MB']:.0f} |"
        for r in rows
    ]
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    dofs = [r["dofs"] for r in rows]
    ax.loglog(dofs, [r["step_s"] for r in rows], "o-", label=f"step time, {args.ranks} ranks")
    ax.loglog(dofs, [rows[0]["step_s"] * d / dofs[0] for d in dofs], "k--", lw=1, label="linear in dofs")
    ax.set_xlabel("dofs")
    ax.set_ylabel("time per Newmark step (s)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title(f"{title}: per-step cost against size")
    fig.tight_layout()
    fig.savefig(stem.with_suffix(".png"), dpi=120)
    print(f"wrote {stem}.md, .csv, .png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
