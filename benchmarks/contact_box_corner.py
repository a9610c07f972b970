"""A cube leaning into a closed box 1 mm around it, where nodes press two walls at once
(docs/limits.md): the paper's gelatin block (50 x 50 x 25 mm, 6 x 6 x 3 cells), fixed at its
base, gravity tilted by --angles degrees toward +x, inside a 12-triangle box 1 mm from every
face (tests/test_contact_solvers.py's scene), linear and neo-Hookean. For each lean: whether
the settled state is found, in what time, and at the state Newton ended in the pressed nodes
within 0.5 mm of two walls: where they started, how far each is inside the walls it presses
(negative: past), and the contact pressure vector on it. With a scalar multiplier the linear
block stopped at all three angles (this file at commit 797ca56).
Writes benchmarks/results/contact_box_corner.md. One rank.

    python benchmarks/contact_box_corner.py [--angles 20,46,90] [--models linear,neo-hookean]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import meshio
import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import logs  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.errors import SolverError  # noqa: E402
from fenics_brainshift.runner import Simulation  # noqa: E402
from fenics_brainshift.scene import scene_from_dict  # noqa: E402

L, H, GAP = 0.05, 0.025, 0.001  # m
NEAR = 0.5e-3  # m: a node this near two walls is in the box's inner edge
WALLS = ("x = -1 mm", "x = L + 1 mm", "y = -1 mm", "y = L + 1 mm", "z = H + 1 mm")


def box(path: Path) -> str:
    """The closed box GAP around the block (12 triangles, outward normals)."""
    (x0, y0, z0), (x1, y1, z1) = (-GAP, -GAP, -GAP), (L + GAP, L + GAP, H + GAP)
    P = np.array(
        [[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0], [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]]
    )
    quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [1, 2, 6, 5], [0, 4, 7, 3]]
    tris = [[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads]
    meshio.write(str(path), meshio.Mesh(P, [("triangle", np.array(tris))]), binary=True)
    return str(path)


def lean(angle_deg: float, skull: str, model: str) -> dict:
    a = np.radians(angle_deg)
    data = {
        "mesh": {"shape": "box", "size": [L, L, H], "cells": [6, 6, 3]},
        "material": {"E": 729.0, "nu": 0.48, "density": 1048.0, "model": model},
        "gravity": {"vector": [9.81 * np.sin(a), 0.0, -9.81 * np.cos(a)]},
        "fixed": [{"where": "z < 1e-9"}],
        "time": {"mode": "quasi-static"},
        "skull": {"file": skull},
    }
    sim = Simulation(scene_from_dict(data), MPI.COMM_WORLD)
    sim.setup()
    t = time.perf_counter()
    try:
        sim.solve_to_settled(0.0)
        outcome = "settled"
    except SolverError as exc:
        outcome = "stops: " + str(exc).split(";")[0]
    seconds = time.perf_counter() - t
    contact = sim.contact
    state = contact._state(sim.u)  # (where Newton stopped, or settled)
    y, normal, pressed = state.y, state.normal, contact._pressed(state.phi)
    room = np.column_stack([y[:, 0] + GAP, L + GAP - y[:, 0], y[:, 1] + GAP, L + GAP - y[:, 1], H + GAP - y[:, 2]])
    nearest = np.sort(room, axis=1)
    corner = np.flatnonzero(pressed & (nearest[:, 1] < NEAR))
    rows = []
    for i in corner:
        two = np.argsort(room[i])[:2]
        rows.append(
            {
                "start_mm": contact.X[i] * 1e3,
                "walls": [WALLS[w] for w in two],
                "room_um": room[i, two] * 1e6,
                "pressure": state.p[i] * normal[i],
            }
        )
    deepest = contact.penetration(sim.u)
    sim.destroy()
    return {
        "model": model,
        "deepest": deepest,
        "angle": angle_deg,
        "outcome": outcome,
        "seconds": seconds,
        "pressed": int(pressed.sum()),
        "corner": rows,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--angles", default="20,46,90")
    parser.add_argument("--models", default="linear,neo-hookean")
    args = parser.parse_args()
    logs.configure("WARNING")
    folder = Path(tempfile.mkdtemp(prefix="brainshift-box-"))
    skull = box(folder / "box.stl")
    results = [lean(float(a), skull, m) for m in args.models.split(",") for a in args.angles.split(",")]
    lines = [
        "# A cube leaning into a closed box 1 mm around it: nodes pressed by two walls",
        "",
        f"{machine_line()}; one rank; `python benchmarks/contact_box_corner.py --angles {args.angles} --models "
        f"{args.models}`. The paper's gelatin block, fixed at its base, gravity tilted toward +x; the skull a "
        "12-triangle box 1 mm from every face, [skull] tolerance 1e-5 m. Time: the settled state's solve. "
        f"Corner nodes: pressed nodes within {NEAR * 1e3:g} mm of two walls at the state Newton ended in; "
        "room: how far inside each wall (negative: past it); pressure: the contact pressure vector on the "
        "node (Pa).",
        "",
    ]
    for r in results:
        lines += [
            f"## {r['model']}, {r['angle']:g} degrees: {r['outcome']} ({r['seconds']:.2f} s, "
            f"{r['pressed']} pressed nodes, deepest {r['deepest'] * 1e6:.2f} um past the skull)",
            "",
        ]
        if not r["corner"]:
            lines += ["No pressed node within 0.5 mm of two walls.", ""]
            continue
        lines += ["| start (mm) | walls | room (um) | pressure (Pa) |", "|---|---|---|---|"]
        for c in r["corner"]:
            lines.append(
                f"| {', '.join(f'{v:.1f}' for v in c['start_mm'])} | {' and '.join(c['walls'])} | "
                f"{', '.join(f'{v:.1f}' for v in c['room_um'])} | "
                f"({', '.join(f'{v:.1f}' for v in c['pressure'])}) |"
            )
        lines.append("")
    out = ROOT / "benchmarks" / "results" / "contact_box_corner.md"
    out.write_text("\n".join(lines))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
