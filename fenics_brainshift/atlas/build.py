"""An atlas: the settled states of a scene over its scenarios (`brainshift atlas`).

The modes are solved on the scene's model once built: one factor of K serves every mode of a
linear body (the loads change, K does not); each settled state starts from the last one (the
levels of a pose as the fluid drains), so the follower fixed point needs few iterations. With
a [skull] every mode is the full model's contact state (augmented-Lagrangian Newton):
contact-free modes pass the skull wherever it holds the brain, and no combination of them is
inside it; each pose's first (highest) level is solved from rest, the next ones from the last
two extrapolated (predict_start), and the swelling modes from the prior state (docs/update.md,
"The skull").
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .. import compat, formats
from ..errors import SolverError
from ..logs import get_logger
from ..memory import peak_memory_mb
from ..scene.body import Swelling
from . import groups, store
from .locate import MeshLocator
from .mode_solves import predict_start, solve_family_mode, solve_from_prior
from .resection import StagedRegion, stage_surface
from .rows import SKULL_SLACK
from .scenarios import clip_levels, family, stiffness, swelling_modes

log = get_logger(__name__)
WHOLE_BODY = "x > -1e6"  # the whole-brain region of a scene without [[swelling]]
MODE_TOLERANCE = 0.5 * SKULL_SLACK  # m: the modes' contact tolerance (_mode_tolerance)
# Newton's relative residual for the modes (a run's is 1e-9): on the 5 mm brain with a 3 mm gap the
# modes of 13 levels at one pose move by 0.006 mm at most against 1e-6 (benchmarks/results/
# skull_atlas.md; 0.011 mm on the 10 mm test atlas): hundredths of a millimetre,
# against the update's noise of tenths and the contact's tolerance of 0.05 mm, for 6.2 Newton
# iterations a state against 8.9
MODE_RTOL = 1e-4
MAX_SKIPPED = 0.1  # of the family's modes that may be left out (settled neither way) before the atlas fails


def build(
    scene, vary: dict, comm, source: str = "", sets=(), ranks_per_mode: int | None = None, resection=None
) -> tuple[store.Atlas | None, dict]:
    """The atlas of a quasi-static scene (on rank 0; None elsewhere) and its timings: the
    family's drain/pose states, the scene's own (the prior) and one swelling mode a region;
    the ranks shared among groups of ``ranks_per_mode`` (atlas/groups.py). With a resection
    (atlas/resection.py) the same again after each of its stages, on what is left: the
    atlas's ``stages``, each an Atlas of its own."""
    from ..fit.forward import ForwardModel
    from ..outputs.vertices import GlobalVertices
    from ..runner.build import cell_selector

    start = time.perf_counter()
    scene = dataclasses.replace(_mode_tolerance(scene), remove=())  # (a resection is staged here)
    swelling = swelling_modes(scene, vary)
    stiff = stiffness(scene, vary)
    solved = scene
    if not scene.swelling:  # the whole body, held at no change in the family's modes
        solved = dataclasses.replace(solved, swelling=(Swelling(volume_change=swelling[0].mode, where=WHOLE_BODY),))
    team = groups.split(comm, ranks_per_mode)
    cuts, staged = (), None
    if resection is not None:
        up = -np.asarray(scene.gravity.vector, dtype=float)
        select = cell_selector(scene, resection.region)
        staged = StagedRegion(select, up, resection.stages, team.comm, resection.describe())
        cuts = staged.cuts()
    try:
        forward = ForwardModel(solved, team.comm, newton_rtol=MODE_RTOL, cuts=cuts)
    except BaseException:
        team.free()
        raise
    t_end = scene.settled_time  # the drained state, whatever [time] end says
    priors = [float(r.at(t_end)) for r in scene.swelling] if scene.swelling else [0.0]
    vertices = GlobalVertices(forward.model.mesh)
    fine = forward._fine_surface()
    fine_points = None if fine is None else (fine.points, fine.triangles)
    heights = forward.heights()
    grid = family(scene, vary, heights)
    if "fluid.level" not in vary and "fluid.level" in grid[0]:
        grid = clip_levels(grid, heights)
    grid = comm.bcast(grid, root=0)  # (every group the same grid: rank 0's)
    setup_s = time.perf_counter() - start
    if team.count > 1:
        log.info(
            "atlas: %d ranks in %d groups of %d, each solving whole poses on its own copy of the model",
            comm.size,
            team.count,
            team.ranks_per_mode,
        )
    prior_values = {}  # the scene's own scenario: its final level, its pose
    if scene.fluid is not None and scene.fluid.volume is None and scene.fluid.level:
        prior_values["fluid.level"] = float(scene.fluid.level(t_end))
    swell = _Swelling(forward.model.growth.regions, priors)
    stages, clock = [], {}
    try:
        for stage in range(len(cuts) + 1):
            stage_start = time.perf_counter()
            removal = None
            if stage:
                forward.sim.cut_now([stage - 1])
                tissue = forward.model.tissue
                removal = {
                    **forward.sim.removals[-1],
                    "removed_fraction": tissue.removed_fraction,
                    "removed_ml": (tissue.total_volume - tissue.volume()) * 1e6,
                }
                del removal["at"], removal["t"]
                above = float(staged.thresholds[stage - 1])  # (the region's cells above this height, m along up)
                removal["above_m"] = above if np.isfinite(above) else None
            timed = clock if not stage else {}  # (the stages' are their stages_s)
            modes = _modes(forward, grid, team, comm, swelling, swell, prior_values, vertices, timed)
            present = None
            if forward.model.tissue is not None:
                present = vertices.cell_values(forward.model.tissue.indicator)
            stages.append((modes, present, removal, time.perf_counter() - stage_start))
    finally:
        solves = comm.allreduce(forward.solves if team.root else 0)
        skull = forward.sim.contact.skull if forward.sim.contact is not None else None
        compliance = _compliance(forward)
        forward.destroy()
        team.free()
    seconds = {"setup_s": setup_s, "modes_s": stages[0][3]}
    seconds.update({k: round(v, 3) for k, v in clock.items()})  # (group 0's: family_s, prior_and_swelling_s)
    peak_mb = max(comm.allgather(peak_memory_mb()))  # (a rank's: the one that held most, so far)
    if len(stages) > 1:
        seconds["stages_s"] = [round(s[3], 3) for s in stages[1:]]
    if comm.rank != 0:
        return None, seconds
    info = {
        "scene": str(source),
        "set": list(sets),
        "scene_name": scene.name,
        "ranks": comm.size,
        "ranks_per_mode": team.ranks_per_mode,
        "peak_memory_mb_a_rank": round(peak_mb),
        "dolfinx_version": compat.DOLFINX_VERSION,
        "material": scene.material.model,
        "gravity": [float(c) for c in scene.gravity.vector],
        "prior": prior_values,
        "stiffness": stiff,
        "probes": {k: [float(c) for c in v] for k, v in scene.probes.items()},
        "frame": "RAS" if scene.mesh.file and formats.is_label_volume(scene.mesh.file) else None,
        "contact_tolerance_m": scene.skull.tolerance if scene.skull is not None else None,
        "contact_compliance": compliance,
    }
    atlases = []
    for stage, ((vertex_modes, prior_vertex, scenarios, skipped), present, removal, stage_s) in enumerate(stages):
        tetrahedra = vertices.tetrahedra if present is None else vertices.tetrahedra[present > 0.5]
        surface = fine_points
        if stage:
            surface = stage_surface(vertices.points, vertices.tetrahedra, present > 0.5, fine_points)
        atlas = _assembled(vertices.points, tetrahedra, vertex_modes, prior_vertex, scenarios, surface, skull)
        atlas.info = {
            **info,
            "left_out": [{"values": values, "why": why} for _, values, why in skipped],
            "modes_s": round(stage_s, 3),
        }
        if stage:
            atlas.info["stage"] = {"number": stage, "of": len(stages) - 1, "region": resection.describe(), **removal}
        atlases.append(atlas)
    atlas = atlases[0]
    # rank 0 holds the most at the end, every mode gathered and the regulariser made of them
    # (benchmarks/results/patient_resolution.md: its command's peak against atlas.json's)
    atlas.info["peak_memory_mb_a_rank"] = round(max(peak_mb, peak_memory_mb()))
    atlas.info.update({"settled_states": solves, **{k: v for k, v in seconds.items() if k != "stages_s"}})
    atlas.info["setup_s"] = round(setup_s, 3)
    atlas.stages = atlases[1:]
    if atlas.stages:
        atlas.info["resection"] = {
            "region": resection.describe(),
            "given_as": resection.given_as,
            "stages": [a.info["stage"] for a in atlas.stages],
            "stages_s": seconds["stages_s"],
        }
    return atlas, seconds


def _modes(forward, grid, team, comm, swelling, swell, prior_values, vertices, clock: dict) -> tuple:
    """One stage's modes on rank 0: (vertex modes (M, N, 3), the prior, scenarios, left out);
    empty elsewhere. The family dealt among the groups by whole chains; the prior and the
    swelling modes by group 0. clock (on group 0): the seconds of its chains and of the prior
    with the swelling modes, and how many family modes it solved."""
    dealt = groups.share(groups.chains(grid, _pose), team.count, head_start=1 + len(swelling))
    family_modes, skipped, prior_vertex, swollen, scenarios = [], [], None, [], []
    failed = None
    try:
        start = time.perf_counter()
        family_modes, skipped = _family_states(forward, grid, vertices, dealt[team.index])
        if team.index == 0:  # the prior, from rest (its answer then is the same for any dealing)
            clock["family_s"] = time.perf_counter() - start  # (group 0's chains: what a chain costs)
            clock["family_modes"] = len(family_modes) + len(skipped)
            start = time.perf_counter()
            forward.start_from_rest()
            forward.solve(prior_values)
            prior_vertex = vertices.values(forward.sim.u)
            swollen = _swelling_states(forward, swelling, swell, prior_values, vertices, scenarios)
            clock["prior_and_swelling_s"] = time.perf_counter() - start
    except Exception as exc:  # (any: the other groups would wait for this one in the allgather below)
        failed = exc
    messages = [m for m in comm.allgather(None if failed is None else str(failed)) if m]
    if messages:  # (one group's failure ends every group's build, each rank saying the first)
        raise failed if failed is not None else SolverError(messages[0])
    family_modes = groups.to_rank_0(team, family_modes if team.root else [])
    skipped = groups.to_rank_0(team, skipped if team.root else [])
    left_out = comm.bcast(len(skipped) if comm.rank == 0 else 0, root=0)
    if left_out > MAX_SKIPPED * len(grid):
        raise SolverError(
            f"atlas: {left_out} of {len(grid)} modes settled neither from the last mode nor from rest "
            f"(more than {MAX_SKIPPED:.0%})"
        )
    if comm.rank != 0:
        return None, None, [], []
    family_modes.sort(key=lambda item: item[0])
    skipped.sort(key=lambda item: item[0])
    vertex_modes = np.array([u for _, u in family_modes] + [v - prior_vertex for v in swollen])
    scenarios = [{"kind": "family", "values": grid[i]} for i, _ in family_modes] + scenarios
    return vertex_modes, prior_vertex, scenarios, skipped


class _Swelling:
    """The swelling regions' volume changes, set on the model: the scene's (the priors), or one
    region's changed to its mode's."""

    def __init__(self, regions: list, priors: list[float]):
        self.regions, self.priors = regions, priors
        self.set(priors)

    def set(self, changes) -> None:
        for i, value in enumerate(changes):
            self.regions[i] = (self.regions[i][0], lambda t, v=value: v)


def _family_states(forward, grid: list[dict], vertices, mine: list[int]) -> tuple[list, list]:
    """The settled state of each scenario of the grid numbered in ``mine`` (whole chains), at
    the vertices: ([(index, state)] on the group's root, [(index, values, why)] left out). Each
    chain's first level starts from rest; the next ones from the last (with the skull, from the
    last two extrapolated: predict_start); with the skull a mode that settles neither way is left
    out, up to MAX_SKIPPED of the grid."""
    states, skipped = [], []
    contact = forward.sim.contact is not None
    last = []  # the pose's last settled states (level, u, multipliers), for the next one's start
    for i in mine:
        values = grid[i]
        if i == 0 or _pose(values) != _pose(grid[i - 1]):  # a chain's first: from rest, in any group
            forward.start_from_rest()
            last = []
        elif contact:  # from rest after a skip too; else from the last two
            forward.from_rest = bool(skipped and skipped[-1][0] == i - 1)
            last = [] if forward.from_rest else last
            if len(last) == 2 and not forward.continued:
                predict_start(forward, last, values)
        else:
            forward.from_rest = False
        try:
            solve_family_mode(forward, values)
        except SolverError as exc:
            if not contact or forward.continued or len(skipped) + 1 > MAX_SKIPPED * len(grid):
                raise  # (without the skull there is no other start to try: the failure stands)
            log.warning(
                "atlas: mode %d of %d %s left out: it did not settle from the last mode nor from rest (%s)",
                i + 1,
                len(grid),
                values,
                exc,
            )
            skipped.append((i, values, str(exc)))
            continue
        if contact:
            level = values.get("fluid.level")
            last = last[-1:] + [(level, forward.sim.u.x.array.copy(), forward.sim.contact.multipliers.copy())]
        state = vertices.values(forward.sim.u)
        if state is not None:
            states.append((i, state))
        log.info("atlas: mode %d of %d %s", i + 1, len(grid), values)
    return states, skipped


def _swelling_states(
    forward, swelling: list, swell: _Swelling, prior_values: dict, vertices, scenarios: list[dict]
) -> list:
    """Each swelling region's settled state with its volume change stepped, from the prior
    state the forward model holds (solve_from_prior); its scenario appended to scenarios."""
    contact = forward.sim.contact
    prior_u = forward.sim.u.x.array.copy()
    prior_multipliers = contact.multipliers.copy() if contact is not None else None
    swollen = []
    for k, mode in enumerate(swelling):
        changes = list(swell.priors)
        changes[k] = mode.mode
        swell.set(changes)
        solve_from_prior(forward, prior_values, prior_u, prior_multipliers)
        swollen.append(vertices.values(forward.sim.u))
        scenarios.append(
            {
                "kind": "swelling",
                "region": mode.name,
                "index": mode.index,
                "prior": mode.prior,
                "step": mode.mode - mode.prior,
                "lower": mode.lower,
                "upper": mode.upper,
            }
        )
    swell.set(swell.priors)
    return swollen


def _assembled(
    points, tetrahedra, U: np.ndarray, prior_vertex: np.ndarray, scenarios: list[dict], fine_points, skull
) -> store.Atlas:
    """The atlas's arrays from its modes U (M, N, 3) at the vertices: the Gram matrices the
    update solves with, the fine surface's modes (P1: barycentric in each point's cell) and the
    skull's triangles."""
    flat = U.reshape(len(U), -1)
    n = len(points)
    atlas = store.Atlas(
        points,
        tetrahedra,
        U,
        prior_vertex,
        flat @ flat.T / n,
        flat @ prior_vertex.ravel() / n,
        float(prior_vertex.ravel() @ prior_vertex.ravel() / n),
        scenarios,
    )
    if fine_points is not None:  # the fine surface follows the vertices as in a run
        atlas.surface_points, atlas.surface_triangles = fine_points
        index, weight, _ = MeshLocator(atlas.points, atlas.tetrahedra).weights(fine_points[0])
        atlas.surface_modes = np.array([np.einsum("nj,njd->nd", weight, u[index]) for u in U])
        atlas.prior_surface = np.einsum("nj,njd->nd", weight, prior_vertex[index])
    if skull is not None:
        atlas.skull_triangles, atlas.skull_gap = skull.triangles, skull.gap
    return atlas


def _compliance(forward) -> dict | None:
    """What the exact contact preconditioner kept (linalg/compliance.py): the columns of K^-1
    solved (one a direction a pressed node's block needed: one to three a node) and the dense
    compliance G between them, in MB on every rank; None without it."""
    exact = getattr(getattr(forward.sim.static, "engaged", None), "_exact", None)
    if exact is None:
        return None
    G = exact.compliance.G
    return {"columns": int(exact.compliance.columns), "megabytes": round(G.nbytes / 1e6, 1)}


def _mode_tolerance(scene):
    """The scene with its contact (the modes' and the prior's) settled to MODE_TOLERANCE: the
    update's skull rows allow SKULL_SLACK past the skull, so a tighter state changes no update
    and costs more (benchmarks/results/skull_atlas.md), and a looser one would let the modes
    pass the skull by more than the rows allow."""
    if scene.skull is None or scene.skull.tolerance == MODE_TOLERANCE:
        return scene
    log.info(
        "atlas: the modes' contact settled to %g mm, not the scene's [skull] tolerance of %g mm (the update's "
        "skull rows allow %g mm)",
        MODE_TOLERANCE * 1e3,
        scene.skull.tolerance * 1e3,
        SKULL_SLACK * 1e3,
    )
    return dataclasses.replace(scene, skull=dataclasses.replace(scene.skull, tolerance=MODE_TOLERANCE))


def _pose(values: dict) -> tuple:
    return tuple(sorted((k, v) for k, v in values.items() if k != "fluid.level"))
