"""One settled state of the 5 mm brain on one rank and on two, by each solver kind: which
solver each rank count should use, and what two ranks gain.

Two settled states after the drain (t = 10 s, level 30 mm): the linear brain with follower
loading (the Anderson fixed point, nine solves with one factor or preconditioner), and the same
with the gap skull 3 mm out (Newton with contact). Each (kind, ranks) its own process under
mpirun, one after another; the time from the scene to the answer, in three parts: the model
(mesh, spaces, loads), the setup (K assembled, factored or its preconditioner built) and the
solve; the median of --repeat runs for the direct kinds, one run for the Krylov kinds (tens of
seconds each). Writes benchmarks/results/settled_ranks.{md,json}.

    python benchmarks/settled_ranks.py [--repeat 3]

(run as `python benchmarks/settled_ranks.py --one KIND CASE` under mpirun: one measurement,
printed as JSON.)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

KINDS = ("cholesky", "lu", "cg-gamg", "cg-hypre")
DIRECT = ("cholesky", "lu")
CASES = {"follower": [], "skull": ["skull.gap=0.003"]}
SETS = ["mesh.voxel=0.005", "time.mode=quasi-static", "fluid.level=0.03", "output.pictures=false"]


def one(kind: str, case: str) -> None:
    """One settled state on this communicator; rank 0 prints its parts as JSON."""
    import numpy as np
    from mpi4py import MPI

    from fenics_brainshift.data import scene_path
    from fenics_brainshift.runner import Simulation
    from fenics_brainshift.scene import load_scene

    comm = MPI.COMM_WORLD

    def now() -> float:
        comm.Barrier()
        return time.perf_counter()

    t0 = now()
    sim = Simulation(load_scene(scene_path("brain"), [*SETS, f"solver.kind={kind}", *CASES[case]]), comm)
    t1 = now()
    sim.setup()
    t2 = now()
    sim.solve_to_settled(10.0)
    t3 = now()
    largest = comm.allreduce(float(np.abs(sim.u.x.array).max(initial=0.0)), op=MPI.MAX)
    if comm.rank == 0:
        print(
            json.dumps(
                {
                    "model_s": t1 - t0,
                    "setup_s": t2 - t1,
                    "solve_s": t3 - t2,
                    "total_s": t3 - t0,
                    "solves": sim.solves.count,
                    "krylov_its": int(sum(sim.solves.iterations)),
                    "largest_mm": largest * 1e3,
                    "dofs": sim.model.sizes()["dofs"],
                }
            ),
            flush=True,
        )


def measure(kind: str, case: str, ranks: int) -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1"}
    command = [sys.executable, __file__, "--one", kind, case]
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), *command]
    done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=1800)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--one", nargs=2, metavar=("KIND", "CASE"))
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "settled_ranks"))
    args = parser.parse_args()
    if args.one:
        one(*args.one)
        return
    from fenics_brainshift.bench import machine_line

    rows = []
    for case in CASES:
        for kind in KINDS:
            for ranks in (1, 2):
                runs = [measure(kind, case, ranks) for _ in range(args.repeat if kind in DIRECT else 1)]
                row = {"case": case, "kind": kind, "ranks": ranks, "runs": len(runs)}
                for key in ("model_s", "setup_s", "solve_s", "total_s"):
                    row[key] = statistics.median(r[key] for r in runs)
                row.update({k: runs[-1][k] for k in ("solves", "krylov_its", "largest_mm", "dofs")})
                rows.append(row)
                print(row, flush=True)
    out = Path(args.out)
    out.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")
    best = {}
    for r in rows:
        key = (r["case"], r["ranks"])
        if key not in best or r["total_s"] < best[key]["total_s"]:
            best[key] = r
    lines = [
        "# One settled state of the 5 mm brain on one rank and on two\n",
        f"{machine_line()}; `python benchmarks/settled_ranks.py --repeat {args.repeat}`; the bundled brain at 5 mm "
        f"({rows[0]['dofs']:,} dofs), the settled state after the drain (level 30 mm), linear, follower loading; "
        "skull: the gap skull 3 mm out (Newton with contact). Each (kind, ranks) its own process; seconds from the "
        "scene to the answer: model (mesh, spaces, loads), setup (K assembled and factored, or its preconditioner "
        f"built), solve; the median of {args.repeat} runs for the direct kinds, one for the Krylov kinds. "
        "cholesky: CHOLMOD on one rank, MUMPS on two; lu: MUMPS.\n",
        "| case | kind | ranks | model s | setup s | solve s | **total s** | two ranks / one | solves | Krylov its "
        "| largest mm |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        one_rank = next(o for o in rows if o["case"] == r["case"] and o["kind"] == r["kind"] and o["ranks"] == 1)
        ratio = "" if r["ranks"] == 1 else f"{r['total_s'] / one_rank['total_s']:.2f}"
        lines.append(
            f"| {r['case']} | {r['kind']} | {r['ranks']} | {r['model_s']:.2f} | {r['setup_s']:.2f} | "
            f"{r['solve_s']:.2f} | **{r['total_s']:.2f}** | {ratio} | {r['solves']} | {r['krylov_its']} | "
            f"{r['largest_mm']:.4f} |"
        )
    lines.append("\nThe fastest kind at each rank count, and two ranks' best against one rank's best:\n")
    for case in CASES:
        a, b = best[(case, 1)], best[(case, 2)]
        lines.append(
            f"- {case}: one rank {a['kind']} {a['total_s']:.2f} s, two ranks {b['kind']} {b['total_s']:.2f} s: "
            f"{b['total_s'] / a['total_s']:.2f}"
        )
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
