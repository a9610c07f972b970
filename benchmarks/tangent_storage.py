"""The Newton tangent in scalar (AIJ) against 3x3-block (BAIJ) storage, on the bundled brain.

Assembly of the linear stiffness and of the neo-Hookean tangent into a matrix made once
(the Newton iteration's pattern), and one product, in both storages; median of REPEAT.
Writes benchmarks/results/tangent_storage.md.

    python benchmarks/tangent_storage.py [--voxel 0.005]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_matrix, create_matrix
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import (  # noqa: E402
    compat,  # noqa: E402
    load_scene,
    logs,
)
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.compat import DOLFINX_VERSION  # noqa: E402
from fenics_brainshift.runner import build_model  # noqa: E402

REPEAT = 7


def _median(action) -> float:
    times = []
    for _ in range(REPEAT):
        t0 = time.perf_counter()
        action()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--voxel", type=float, default=0.005)
    args = p.parse_args(argv)
    logs.configure("WARNING")
    model = build_model(load_scene("brain", [f"mesh.voxel={args.voxel}", "material.model=neo-hookean"]), MPI.COMM_SELF)
    V = model.V
    u, v, du = fem.Function(V), ufl.TestFunction(V), ufl.TrialFunction(V)
    forms = {
        "linear stiffness": compat.form(model.material.tangent(u, du, v)),
        "neo-Hookean tangent": compat.form(model.hyperelastic.tangent(u, du, v)),
    }
    rows = []
    for name, form in forms.items():
        row = {"form": name}
        for storage in ("aij", "baij"):
            A = create_matrix(form, storage)

            def assemble():
                A.zeroEntries()
                assemble_matrix(A, form)
                A.assemble()

            assemble()
            x, y = A.createVecRight(), A.createVecLeft()
            x.set(1.0)
            row[storage] = (_median(assemble), _median(lambda: A.mult(x, y)))
            A.destroy()
        rows.append(row)
    lines = [
        "# The Newton tangent: scalar (AIJ) against 3x3-block (BAIJ) storage\n",
        f"{machine_line()}; DOLFINx {DOLFINX_VERSION}; one rank; bundled brain, {args.voxel * 1e3:g} mm voxels, "
        f"{model.sizes()['nodes']} nodes; `python benchmarks/tangent_storage.py`; median of {REPEAT}.\n",
        "| form | assembly AIJ (ms) | assembly BAIJ (ms) | ratio | product AIJ (ms) | product BAIJ (ms) | ratio |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        (a_asm, a_mul), (b_asm, b_mul) = r["aij"], r["baij"]
        lines.append(
            f"| {r['form']} | {1e3 * a_asm:.1f} | {1e3 * b_asm:.1f} | {a_asm / b_asm:.1f} | "
            f"{1e3 * a_mul:.2f} | {1e3 * b_mul:.2f} | {a_mul / b_mul:.1f} |"
        )
    out = ROOT / "benchmarks" / "results" / "tangent_storage.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
