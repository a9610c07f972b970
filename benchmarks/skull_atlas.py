"""What an atlas with the skull costs, and why its swelling modes start from the prior state.

1. `brainshift atlas` of the bundled brain at --voxel with a skull --gap out: --levels levels
   at one pose and the whole-brain swelling mode; the seconds, Newton and GMRES iterations a
   settled state, and factorisations, built five ways in the same run: the atlas's (levels as
   the fluid drains, each start extrapolated from the pose's last two states, Newton's relative
   residual build.MODE_RTOL, the exact contact preconditioner on K's one factor:
   stepping/exact_contact.py; Newton's first solve looser, newton.FIRST_LOOSER); the same with
   each level from the last state alone; with the first solve to the target at once; residual
   1e-6; the levels ascending (refilled); a refactored preconditioner (a factor of K and the
   pressed nodes rebuilt as they move, residual 1e-9); the atlas's with the scene's tighter
   contact tolerance. How far their modes are apart.
2. The whole brain shrunk by 4 % at the scene's own level and pose, solved twice: from rest
   (loads grown from zero) and from the prior state (as the atlas does); how far apart the two
   contact states are, and how far each is past the skull. Where the skull's inner surface is
   concave the equilibrium need not be unique (docs/update.md, "The skull").

Writes benchmarks/results/skull_atlas.md. One process, one rank.

    python benchmarks/skull_atlas.py [--voxel 0.005] [--gap 0.003] [--levels 13]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import load_scene, logs  # noqa: E402
from fenics_brainshift.atlas import build as building  # noqa: E402
from fenics_brainshift.atlas.build import WHOLE_BODY, build  # noqa: E402
from fenics_brainshift.atlas.mode_solves import solve_from_prior  # noqa: E402
from fenics_brainshift.atlas.rows import SKULL_SLACK  # noqa: E402
from fenics_brainshift.atlas.scenarios import parse_vary  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.fit import ForwardModel  # noqa: E402
from fenics_brainshift.outputs.vertices import GlobalVertices  # noqa: E402
from fenics_brainshift.scene.body import Swelling  # noqa: E402
from fenics_brainshift.stepping import newton as newton_module  # noqa: E402
from fenics_brainshift.stepping.newton import NewtonStatic  # noqa: E402
from fenics_brainshift.stepping.solves import Solves  # noqa: E402

SHRINK = -0.04
LOWEST, HIGHEST, ANGLE = (
    -0.015,
    0.045,
    -12.0,
)  # the levels' range (m; the default atlas's at the brain's 30 mm) and the pose


class Counted:
    """Solves' GMRES iterations and factorisations, counted over a block of work."""

    def __enter__(self):
        self.iterations, self.factors, self.newton = 0, 0, 0
        self._record, self._reset = Solves.record, Solves.reset
        self._iterate = newton_module.newton_iterate
        counter = self

        def iterate(*args, **kwargs):
            converged, history = counter._iterate(*args, **kwargs)
            counter.newton += len(history) - 1
            return converged, history

        newton_module.newton_iterate = iterate

        def record(solves, its, seconds, x, t):  # every solve, whichever Krylov method made it
            counter.iterations += its
            counter._record(solves, its, seconds, x, t)

        def reset(solves, A):
            counter.factors += 1
            counter._reset(solves, A)

        Solves.record, Solves.reset = record, reset
        return self

    def __exit__(self, *exc):
        Solves.record, Solves.reset = self._record, self._reset
        newton_module.newton_iterate = self._iterate


def atlas_cost(
    scene,
    levels: int,
    mode_tolerance: float | None = None,
    exact: bool = True,
    rtol: float | None = None,
    predict: bool = True,
    draining: bool = True,
    loose_first: bool = True,
) -> dict:
    """The atlas's cost; mode_tolerance: the modes' contact tolerance (None: the atlas's own,
    build.MODE_TOLERANCE; the scene's [skull] tolerance for the baseline); exact: False for
    the refactored preconditioner (a factor of K and the pressed nodes, rebuilt); rtol: Newton's
    relative residual (None: build.MODE_RTOL); predict: False to start each level from the last
    state alone; draining: False for the levels in ascending order (the first from rest at the
    lowest, then refilled); loose_first: False for Newton's first solve
    with the skull to the tight target at once (newton.FIRST_LOOSER = 1)."""
    vary = parse_vary([f"fluid.level={LOWEST}:{HIGHEST}:{levels}", f"gravity.angle_z={ANGLE}"])
    saved = (
        building.MODE_TOLERANCE,
        NewtonStatic._exact_possible,
        building.MODE_RTOL,
        building.predict_start,
        building.family,
        newton_module.FIRST_LOOSER,
    )
    if not loose_first:
        newton_module.FIRST_LOOSER = 1.0
    building.MODE_TOLERANCE = saved[0] if mode_tolerance is None else mode_tolerance
    building.MODE_RTOL = saved[2] if rtol is None else rtol
    if not exact:
        NewtonStatic._exact_possible = lambda self: False
    if not predict:
        building.predict_start = lambda *args: None
    if not draining:
        building.family = lambda *args: sorted(saved[4](*args), key=lambda s: (building._pose(s), s["fluid.level"]))
    try:
        with Counted() as counted:
            atlas, seconds = build(scene, vary, MPI.COMM_WORLD)
    finally:
        (
            building.MODE_TOLERANCE,
            NewtonStatic._exact_possible,
            building.MODE_RTOL,
            building.predict_start,
            building.family,
            newton_module.FIRST_LOOSER,
        ) = saved
    states = atlas.info["settled_states"]
    modes = {_key(s): u for s, u in zip(atlas.scenarios, atlas.vertex_modes)}
    return {
        "count": len(atlas.scenarios),
        "states": states,
        "modes_s": seconds["modes_s"],
        "per_state_s": seconds["modes_s"] / states,
        "gmres_per_state": counted.iterations / states,
        "newton_per_state": counted.newton / states,
        "factors": counted.factors,
        "tolerance_mm": 1e3 * atlas.info["contact_tolerance_m"],
        "modes": modes,
    }


def _key(scenario: dict) -> tuple:
    return (
        ("swelling", scenario["region"])
        if scenario["kind"] == "swelling"
        else tuple(sorted(scenario["values"].items()))
    )


def modes_apart(a: dict, b: dict) -> dict:
    """How far two atlases' modes of the same scenarios are apart (mm): the largest, the mean
    over nodes and modes, and the nodes more than 1 mm apart in any mode."""
    distance = np.array([np.linalg.norm(a[k] - b[k], axis=1) for k in a])  # (modes, nodes)
    return {
        "max_mm": 1e3 * distance.max(),
        "mean_mm": 1e3 * distance.mean(),
        "nodes_1mm": int((distance.max(axis=0) > 1e-3).sum()),
    }


def shrink_two_ways(scene) -> dict:
    solved = dataclasses.replace(scene, swelling=(Swelling(volume_change=SHRINK, where=WHOLE_BODY),))
    forward = ForwardModel(solved, MPI.COMM_WORLD)
    regions = forward.model.growth.regions
    vertices = GlobalVertices(forward.model.mesh)
    level = {"fluid.level": float(scene.fluid.level(scene.time.end))}

    def swelling(value):
        regions[0] = (regions[0][0], lambda t, v=value: v)

    swelling(0.0)
    forward.solve(level)  # the prior, from rest
    prior_u = forward.sim.u.x.array.copy()
    prior_multipliers = forward.sim.contact.multipliers.copy()
    swelling(SHRINK)
    start = time.perf_counter()
    solve_from_prior(forward, level, prior_u, prior_multipliers)
    from_prior_s = time.perf_counter() - start
    from_prior, past_prior = vertices.values(forward.sim.u), forward.sim.contact.penetration(forward.sim.u)
    forward.from_rest = True
    start = time.perf_counter()
    forward.solve(level)
    from_rest_s = time.perf_counter() - start
    from_rest, past_rest = vertices.values(forward.sim.u), forward.sim.contact.penetration(forward.sim.u)
    forward.destroy()
    apart = np.linalg.norm(from_rest - from_prior, axis=1)
    shift = np.linalg.norm(from_prior, axis=1)
    return {
        "apart_max_mm": 1e3 * apart.max(),
        "apart_mean_mm": 1e3 * apart.mean(),
        "nodes_1mm_apart": int((apart > 1e-3).sum()),
        "nodes": len(apart),
        "shift_max_mm": 1e3 * shift.max(),
        "past_rest_mm": 1e3 * past_rest,
        "past_prior_mm": 1e3 * past_prior,
        "from_rest_s": from_rest_s,
        "from_prior_s": from_prior_s,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--voxel", type=float, default=0.005)
    parser.add_argument("--gap", type=float, default=0.003)
    parser.add_argument("--levels", type=int, default=13)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "skull_atlas.md"))
    args = parser.parse_args()
    logs.configure("WARNING")
    scene = load_scene("brain", [f"mesh.voxel={args.voxel}", f"skull.gap={args.gap}", "time.mode=quasi-static"])
    cost = atlas_cost(scene, args.levels)
    unpredicted = atlas_cost(scene, args.levels, predict=False)  # each level from the last state alone
    tight_first = atlas_cost(scene, args.levels, loose_first=False)  # Newton's first solve to the target at once
    plain = atlas_cost(scene, args.levels, rtol=1e-6, predict=False, loose_first=False)  # residual 1e-6, the last state
    refilled = atlas_cost(scene, args.levels, rtol=1e-6, predict=False, draining=False, loose_first=False)
    former = atlas_cost(scene, args.levels, exact=False, rtol=1e-9, predict=False, draining=False, loose_first=False)
    tight = atlas_cost(scene, args.levels, mode_tolerance=scene.skull.tolerance)
    predicted_apart = modes_apart(cost["modes"], unpredicted["modes"])
    loose_apart = modes_apart(cost["modes"], tight_first["modes"])
    residual_apart = modes_apart(unpredicted["modes"], plain["modes"])
    path_apart = modes_apart(plain["modes"], refilled["modes"])
    preconditioner_apart = modes_apart(refilled["modes"], former["modes"])
    tolerance_apart = modes_apart(cost["modes"], tight["modes"])
    for run in (cost, unpredicted, tight_first, plain, refilled, former, tight):
        print({k: v for k, v in run.items() if k != "modes"}, flush=True)
    shrink = shrink_two_ways(scene)
    print(shrink, flush=True)
    inside = max(shrink["past_rest_mm"], shrink["past_prior_mm"]) <= 1e3 * scene.skull.tolerance
    verdict = (
        "The two starts reach the same state."
        if shrink["apart_max_mm"] <= 0.1
        else "Both are settled"
        + (
            " and inside the skull (to its tolerance): two equilibria of one scene."
            if inside
            else "; one is past the skull by more than its tolerance."
        )
    )

    def row(order, start, rtol, loose, preconditioner, run, bold=False, note=""):
        seconds = f"**{run['per_state_s']:.2f}**" if bold else f"{run['per_state_s']:.2f}"
        return (
            f"| {order} | {start} | {rtol:g} | {loose} | {preconditioner} | {run['tolerance_mm']:g} mm{note} | "
            f"{seconds} | {run['newton_per_state']:.1f} | {run['gmres_per_state']:.0f} | {run['factors']} |"
        )

    command = "python benchmarks/skull_atlas.py" + "".join(
        f" --{k} {v}" for k, v in (("voxel", args.voxel), ("gap", args.gap), ("levels", args.levels))
    )
    text = f"""# An atlas with the skull: its cost, and the swelling mode's start

{machine_line()}; one rank; `{command}`; the bundled brain at {args.voxel * 1e3:g} mm, a skull {args.gap * 1e3:g} mm
out, the scene's [skull] tolerance {scene.skull.tolerance * 1e3:g} mm (the shrunk states below are settled to it).

## The cost of a mode

{args.levels} levels ({LOWEST * 1e3:g} to {HIGHEST * 1e3:g} mm) at one pose (turned {ANGLE:g} degrees about z) and the
whole-brain swelling mode, {cost["count"]} modes, {cost["states"]} settled states (the scene's own prior included);
the goal is 1.5 s a mode. Each row is one `build` of the same scenarios in this run:

| levels in order | a level's start | Newton's residual | first solve looser | preconditioner | contact tolerance | s a settled state | Newton iterations a state | GMRES iterations a state | factorisations |
|---|---|---|---|---|---|---|---|---|---|
{row("draining (the atlas's)", "the last two extrapolated", building.MODE_RTOL, "yes", "exact, K's one factor", cost, bold=True)}
{row("draining", "the last", building.MODE_RTOL, "yes", "exact", unpredicted)}
{row("draining", "the last two extrapolated", building.MODE_RTOL, "no", "exact", tight_first)}
{row("draining", "the last", 1e-6, "no", "exact", plain)}
{row("refilling (levels ascending)", "the last", 1e-6, "no", "exact", refilled)}
{row("refilling", "the last", 1e-9, "no", "refactored", former)}
{row("draining", "the last two extrapolated", building.MODE_RTOL, "yes", "exact", tight, note=" (the scene's)")}

Draining: each pose's first state, solved from rest, is at its highest level, where the fluid
bears the brain and it presses the skull least; the next ones follow the drain. Refilling
(levels ascending): the first at the lowest level, where from rest most nodes press, each Newton
step held back to the first node's contact. Every settled state is an equilibrium inside the
skull to its contact tolerance; how far the rows' modes are apart (mm):

| | largest | mean over nodes and modes | nodes more than 1 mm apart |
|---|---|---|---|
| extrapolated starts / the last state (residual {building.MODE_RTOL:g}) | {predicted_apart["max_mm"]:.3f} | {predicted_apart["mean_mm"]:.4f} | {predicted_apart["nodes_1mm"]} |
| the first solve looser / not | {loose_apart["max_mm"]:.3f} | {loose_apart["mean_mm"]:.4f} | {loose_apart["nodes_1mm"]} |
| residual {building.MODE_RTOL:g} / 1e-6 (each from the last state) | {residual_apart["max_mm"]:.1e} | {residual_apart["mean_mm"]:.1e} | {residual_apart["nodes_1mm"]} |
| draining / refilling (the path) | {path_apart["max_mm"]:.3f} | {path_apart["mean_mm"]:.4f} | {path_apart["nodes_1mm"]} |
| refilling exact / refactored (residual 1e-6 / 1e-9) | {preconditioner_apart["max_mm"]:.1e} | {preconditioner_apart["mean_mm"]:.1e} | {preconditioner_apart["nodes_1mm"]} |
| contact tolerance {cost["tolerance_mm"]:g} / {tight["tolerance_mm"]:g} mm | {tolerance_apart["max_mm"]:.3f} | {tolerance_apart["mean_mm"]:.4f} | {tolerance_apart["nodes_1mm"]} |

A start changes which equilibrium a contact state settles in where the skull's inner surface is
concave, and two states each within the contact tolerance of the skull may be that far apart
(the update's skull rows allow {SKULL_SLACK * 1e3:g} mm past it). The path changes it more:
the draining order follows the operation (the level falls at a fixed pose), as a run of the
scene does. Exact: the preconditioner is K plus the pressed nodes' contact blocks by the
Woodbury formula, two triangular solves with K's one factor an application, each node's
compliance solved once; GMRES is left the follower load's tangent.

## The whole brain shrunk by {-SHRINK * 100:g} %, from rest and from the prior state

| | |
|---|---|
| the two contact states apart, largest | {shrink["apart_max_mm"]:.2f} mm |
| ... on average over the {shrink["nodes"]} nodes | {shrink["apart_mean_mm"]:.3f} mm |
| nodes more than 1 mm apart | {shrink["nodes_1mm_apart"]} |
| past the skull: from rest / from the prior | {shrink["past_rest_mm"]:.4f} / {shrink["past_prior_mm"]:.4f} mm |
| seconds: from rest / from the prior | {shrink["from_rest_s"]:.1f} / {shrink["from_prior_s"]:.1f} |

{verdict} The atlas takes the state reached from the prior: its swelling mode is the change the
swelling makes there.
"""
    Path(args.out).write_text(text)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
