"""What Newton's tangent costs an atlas with the skull: assembled every iteration, or an action.

A linear body against the skull is solved by flexible GMRES preconditioned by K's factor and
the pressed nodes (stepping/exact_contact.py), which only multiplies by the tangent. The
tangent as an action (stepping/tangent_action.py: K with the constraints projected once, the
load's and the contact's blocks applied to S x) against the tangent assembled every iteration
(K copied, the blocks added, the septa's PtAP, the supports' rows; the path before): the same
atlas chain (one pose's levels as the fluid drains, and the swelling mode), built alternately
both ways in this process, --repeats times; the medians, and how far the modes are apart.

    python benchmarks/tangent_action.py [--scene brain] [--voxel 0.005] [--repeats 2] [--levels A:B:N]

The bundled brain at --voxel with the skull 3 mm out and its falx and tentorium; --scene a
prepared patient's scene.toml instead (its own skull and septa). Writes
benchmarks/results/tangent_action.md (a patient: tangent_action_FOLDER.md, FOLDER the
prepared folder's name). One process, one rank.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import load_scene, logs  # noqa: E402
from fenics_brainshift.atlas import scenarios  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.commands.atlas import arguments as atlas_arguments  # noqa: E402
from fenics_brainshift.commands.atlas import main as atlas_command  # noqa: E402
from fenics_brainshift.stepping.static_tangent import StaticTangent  # noqa: E402

BRAIN_SETS = ["skull.gap=0.003", "septum.falx.enabled=true", "septum.tentorium.enabled=true"]


def chain(scene: str, sets: list[str]) -> list[str]:
    """One pose of the default atlas (its first: each turned axis at its first angle), every level."""
    axes = scenarios._default_family(load_scene(scene, overrides=[*sets, "time.mode=quasi-static"]))
    return [
        f"{key}={','.join(f'{v:.6g}' for v in values)}" if key == "fluid.level" else f"{key}={values[0]:g}"
        for key, values in axes.items()
    ]


def build(scene: str, sets: list[str], vary: list[str], out: Path, assembled: bool) -> dict:
    original = StaticTangent.action
    if assembled:  # the path before: the matrix assembled for flexible GMRES every iteration
        StaticTangent.action = lambda self, K, factor: self.matrix(factor)
    try:
        start = time.perf_counter()
        atlas_command(atlas_arguments(scene, out, vary, sets), MPI.COMM_WORLD)
        wall = time.perf_counter() - start
    finally:
        StaticTangent.action = original
    info = json.loads((out / "atlas.json").read_text())
    with h5py.File(out / "atlas.h5") as f:
        modes = f["modes/vertex"][()]
    return {"wall": wall, "modes_s": info["modes_s"], "modes": info["modes"], "nodes": info["nodes"], "u": modes}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="brain")
    parser.add_argument("--voxel", type=float, default=0.005)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument(
        "--levels",
        help="fluid.level=... of the chain (default: the default atlas's; a prepared patient's may pass "
        "the brain's top, which only the default atlas clips)",
    )
    args = parser.parse_args()
    logs.configure("WARNING")
    sets = [f"mesh.voxel={args.voxel}", *BRAIN_SETS] if args.scene == "brain" else []
    vary = chain(args.scene, sets)
    if args.levels:
        if not any(v.startswith("fluid.level=") for v in vary):
            parser.error("--levels: the scene's default atlas varies no fluid level")
        vary = [f"fluid.level={args.levels}" if v.startswith("fluid.level=") else v for v in vary]
    runs = {"action": [], "assembled": []}
    with tempfile.TemporaryDirectory() as tmp:
        build(args.scene, sets, vary, Path(tmp) / "warm", False)  # the JIT cache, unmeasured
        for k in range(args.repeats):
            for way in ("action", "assembled"):
                runs[way].append(build(args.scene, sets, vary, Path(tmp) / f"{way}{k}", way == "assembled"))
                print(way, k, f"{runs[way][-1]['modes_s']:.1f} s", flush=True)
    apart = max(float(np.abs(a["u"] - b["u"]).max()) for a, b in zip(runs["action"], runs["assembled"]))
    median = {way: statistics.median(r["modes_s"] for r in rs) for way, rs in runs.items()}
    first = runs["action"][0]
    name = "the bundled brain" if args.scene == "brain" else f"a prepared patient ({Path(args.scene).parent.name})"
    rows = "\n".join(
        f"| {way} | {median[way]:.1f} | {median[way] / first['modes']:.2f} | "
        f"{median[way] / median['assembled']:.2f} | {', '.join(format(r['modes_s'], '.1f') for r in rs)} |"
        for way, rs in runs.items()
    )
    voxel = f" --voxel {args.voxel}" if args.scene == "brain" else ""  # (a scene file meshes at its own)
    command = f"python benchmarks/tangent_action.py --scene {args.scene}{voxel} --repeats {args.repeats}"
    command += f" --levels {args.levels}" if args.levels else ""
    given = " ".join(f"--vary {v}" for v in vary) + "".join(f" --set {s}" for s in sets)
    text = f"""# Newton's tangent in an atlas with the skull: an action, or assembled every iteration

{machine_line()}; `{command}` (one process, one rank; the two ways alternating, after one unmeasured
build for the JIT cache).

{name}: {first["nodes"]} nodes; `brainshift atlas` of one pose's levels of the default atlas and
the swelling mode ({first["modes"]} modes: `{given}`).

| tangent | modes s (median) | s a mode | of the assembled | each build, s |
|---|---|---|---|---|
{rows}

The modes of the two ways differ by at most {apart * 1e3:.2g} mm (each stored in single precision).
"""
    suffix = "" if args.scene == "brain" else f"_{Path(args.scene).parent.name}"
    out = ROOT / "benchmarks" / "results" / f"tangent_action{suffix}.md"
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
