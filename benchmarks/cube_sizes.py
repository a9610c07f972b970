"""Per-step time, setup time and Krylov iterations of the gelatin cube at the paper's sizes.

The paper (section III-D, Fig. 8) ran 2,890 / 4,851 / 8,788 / 15,376-node cubes with CG on a
GPU. Here each grid runs a few Newmark steps of the bundled cube scene per solver, serially and
under mpirun -n 2, each as its own `brainshift run` process, and the summary.json numbers
go to benchmarks/results/cube_sizes.csv and .md (with the machine and this command).

    .venv/bin/python benchmarks/cube_sizes.py            # all grids, cholesky + cg-gamg, 1 and 2 ranks
    .venv/bin/python benchmarks/cube_sizes.py --steps 5 --solvers cholesky --ranks 1
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

ROOT = Path(__file__).resolve().parents[1]
GRIDS = {  # hexahedra per side -> the paper's node / element counts
    (16, 16, 9): (2890, 11520),
    (20, 20, 10): (4851, 20000),
    (25, 25, 12): (8788, 37500),
    (30, 30, 15): (15376, 67500),
}


def machine() -> str:
    from fenics_brainshift.bench import machine_line

    return machine_line()


def run_case(cells, solver: str, ranks: int, steps: int, workdir: Path, follower: bool) -> dict:
    out = workdir / f"{'x'.join(map(str, cells))}_{solver}_{ranks}"
    cmd = [
        sys.executable,
        "-m",
        "fenics_brainshift.cli",
        "--log-level",
        "WARNING",
        "run",
        "cube",
        "--out",
        str(out),
        "--set",
        f"mesh.cells=[{cells[0]}, {cells[1]}, {cells[2]}]",
        "--set",
        f"solver.kind={solver}",
        "--set",
        f"time.end={steps * 0.05}",
        "--set",
        'output.fields=["displacement"]',
        "--set",
        "output.interval=1000.0",
        "--set",
        f"fluid.follower={'true' if follower else 'false'}",
    ]
    if ranks > 1:
        cmd = [shutil.which("mpirun"), "-n", str(ranks)] + cmd
    env = dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    subprocess.run(cmd, check=True, env=env, cwd=ROOT)
    return json.loads((out / "summary.json").read_text())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=10, help="time steps per case")
    p.add_argument("--solvers", nargs="+", default=["cholesky", "cg-gamg"])
    p.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    p.add_argument(
        "--follower",
        action="store_true",
        help="follower loading as in the demo (several solves per step); default: one solve per step",
    )
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "cube_sizes"))
    args = p.parse_args(argv)

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for cells, (nodes, elements) in GRIDS.items():
            for solver in args.solvers:
                for ranks in args.ranks:
                    s = run_case(cells, solver, ranks, args.steps, Path(tmp), args.follower)
                    assert (s["nodes"], s["cells"]) == (nodes, elements)
                    row = {
                        "nodes": nodes,
                        "elements": elements,
                        "dofs": s["dofs"],
                        "solver": solver,
                        "ranks": ranks,
                        "steps": s["steps"],
                        "setup_s": round(s["setup_s"], 3),
                        "step_ms_median": round(s["step_s_median"] * 1e3, 2),
                        "iterations_mean": round(s["iterations_mean"], 1),
                        "solves_per_step": round(s["linear_solves"] / max(s["steps"], 1), 1),
                        "top_uz_mm": round(s["probes"]["top_centre"][2] * 1e3, 5),
                        "dolfinx": s["dolfinx_version"],
                    }
                    rows.append(row)
                    print(", ".join(f"{k}={v}" for k, v in row.items()), flush=True)

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    command = "python benchmarks/cube_sizes.py " + " ".join(argv if argv is not None else sys.argv[1:])
    lines = [
        f"Machine: {machine()}  ",
        f"Command: `{command.strip()}`  ",
        f"Cube of the bundled cube scene (container drain, follower loading "
        f"{'on, iterated per step' if args.follower else 'off: one solve per step'}), the first "
        f"{args.steps} Newmark steps (dt = 0.05 s) per case; times are medians.",
        "",
        "| nodes | elements | solver | ranks | setup (s) | step (ms) | solves/step | Krylov its/solve | top u_z (mm) |",
        "|---:|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r['nodes']} | {r['elements']} | {r['solver']} | {r['ranks']} | {r['setup_s']:.2f} | "
        f"{r['step_ms_median']:.1f} | {r['solves_per_step']:.1f} | {r['iterations_mean']:.0f} | "
        f"{r['top_uz_mm']:.4f} |"
        for r in rows
    ]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
