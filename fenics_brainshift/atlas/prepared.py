"""The atlas as every update sees it, made once when it is loaded (as a navigation system keeps
it in memory): the weights' bounds and the prior's weights, the mesh's locator, the surface the
points are measured against, and the skull's rows near the prior's state."""

from __future__ import annotations

import time

import numpy as np

from ..surfaces.skull import RigidSkull
from .combine import Constraints, weight_constraints
from .locate import MeshLocator
from .rows import SkullRows
from .store import Atlas
from .surface_patch import MovingSurface

ROUND_OFF = 1e-9  # (relative to the largest) a family weight NNLS leaves this small is round-off (3 mm: 2e-11)


def bounds(atlas) -> tuple[np.ndarray, np.ndarray]:
    """The amplitude bounds of the swelling modes (their coefficient: (theta - prior) / step)."""
    m = len(atlas.scenarios)
    lower, upper = np.zeros(m), np.zeros(m)
    for k, s in enumerate(atlas.scenarios):
        if s["kind"] == "swelling":
            a, b = (s["lower"] - s["prior"]) / s["step"], (s["upper"] - s["prior"]) / s["step"]
            lower[k], upper[k] = min(a, b), max(a, b)
    return lower, upper


def family_sum(atlas) -> tuple[float, float]:
    """The bounds of the family's weights' sum: G0/G over the atlas's range of G (a linear
    body's shift from gravity and the fluid is proportional to 1/G; a swelling's is not)."""
    s = atlas.info.get("stiffness")
    return (s["G"] / s["upper"], s["G"] / s["lower"]) if s else (1.0, 1.0)


def prior_weights(atlas) -> np.ndarray:
    """The weights whose combination is nearest the scene's own prediction (least squares
    over the nodes, within the constraints): where the update starts (once per atlas)."""
    if "prior_weights" not in atlas.once:
        atlas.once["prior_weights"] = _prior_weights(atlas)
    return atlas.once["prior_weights"]


def prepare(atlas: Atlas) -> float:
    """What every update of this atlas needs, made once when it is loaded (as a navigation
    system keeps it in memory): the prior's weights, the mesh's locator, the surface points are
    measured against, the skull's distance tree and rows over the boundary nodes, and the nodes
    near the skull at the prior's weights with their rows (every update's first round) and the
    start inside them. Returns the seconds it took."""
    start = time.perf_counter()
    prior_weights(atlas)
    locator(atlas)
    moving_surface(atlas)
    skull_at_prior(atlas)
    start_inside(atlas)
    return time.perf_counter() - start


def skull_at_prior(atlas):
    """(nodes, constraints): the boundary nodes near the skull at the prior's weights, and the
    weights' constraints with those nodes' rows (combine.Constraints, what the solvers derive
    from them made once); or None without a skull."""
    if "skull_at_prior" not in atlas.once:
        skull, c = skull_rows(atlas), prior_weights(atlas)
        if skull is None:
            atlas.once["skull_at_prior"] = None
        else:
            nodes = skull.near(c)
            constraints = Constraints(*weight_constraints(atlas.family, *bounds(atlas), family_sum(atlas)))
            constraints = constraints.stacked(*skull.rows(c, nodes))
            for derived in ("unit_rows", "partner", "bounds", "slack"):
                getattr(constraints, derived)
            atlas.once["skull_at_prior"] = (nodes, constraints)
    return atlas.once["skull_at_prior"]


def locator(atlas) -> MeshLocator:
    if "locator" not in atlas.once:
        atlas.once["locator"] = MeshLocator(atlas.points, atlas.tetrahedra)
    return atlas.once["locator"]


def _prior_weights(atlas) -> np.ndarray:
    lower, upper = bounds(atlas)
    C, d = weight_constraints(atlas.family, lower, upper, (1.0, 1.0))  # at the scene's own G
    return _nearest_prediction(atlas, C, d)


def start_inside(atlas) -> np.ndarray:
    """The weights nearest the scene's own prediction inside every row of the update's first
    round (the weights' bounds and the skull's rows at the prior's weights): where its first
    fit starts. The prior's own weights can be a little past a skull's rows (a mix of settled
    states, each inside, is not always), and a start past rows that outnumber its free
    weights fell to NNLS from scratch in every update (0.4 s of 0.5 at 3 mm: update_skull_3mm.md
    at commit b59c598). Without a skull, the prior's weights. Once per atlas."""
    if "start_inside" not in atlas.once:
        at_prior = skull_at_prior(atlas)
        if at_prior is None:
            atlas.once["start_inside"] = prior_weights(atlas)
        else:
            constraints = at_prior[1]
            atlas.once["start_inside"] = _nearest_prediction(atlas, constraints.C, constraints.d)
    return atlas.once["start_inside"]


def _nearest_prediction(atlas, C: np.ndarray, d: np.ndarray) -> np.ndarray:
    """argmin R(c) (the mean square distance from the scene's prediction) subject to C c >= d,
    the family's weights NNLS leaves at round-off set to 0 and their sum added to the largest
    (the family's sum, which rows bound, unchanged): at 0 they are, and a start whose every
    weight is free takes the active-set method more steps than it has."""
    from .active_set import least_distance

    H = atlas.gram.copy()
    H[np.diag_indices_from(H)] += 1e-9 * np.trace(H) / len(H)
    c = least_distance(H, atlas.cross, C, d)
    family = np.flatnonzero(atlas.family)
    weights = c[family]
    small = np.abs(weights) <= ROUND_OFF * np.abs(weights).max()
    largest = int(np.argmax(weights))
    weights[largest] += weights[small].sum()
    weights[small] = 0.0
    c[family] = weights
    return c


def combination(c: np.ndarray, modes: np.ndarray) -> np.ndarray:
    """sum_k c_k modes_k over the weights that are not 0 (in float64)."""
    used = np.flatnonzero(c)
    return np.tensordot(c[used], modes[used].astype(np.float64), axes=1)


def moving_surface(atlas) -> MovingSurface:
    """The surface points are measured against (the fine surface, else the mesh's boundary) at
    the prior's state, made once per atlas."""
    if "moving_surface" not in atlas.once:
        if atlas.surface_points is not None:
            surface = MovingSurface(
                atlas.surface_points, atlas.surface_triangles, atlas.surface_modes, atlas.prior_surface
            )
        else:
            boundary = atlas.boundary
            surface = MovingSurface(
                atlas.points[boundary.vertices],
                boundary.triangles,
                boundary.modes,
                atlas.prior_vertex[boundary.vertices],
                by_vertex=boundary.by_node,
            )
        atlas.once["moving_surface"] = surface
    return atlas.once["moving_surface"]


def skull_rows(atlas) -> SkullRows | None:
    """The skull's rows over the mesh's boundary nodes, or None for an atlas without a skull
    (made once per atlas: its distance tree and the nodes' modes)."""
    if atlas.skull_triangles is None:
        return None
    if "skull_rows" not in atlas.once:
        tri = atlas.skull_triangles
        skull = RigidSkull(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3), gap=atlas.skull_gap)
        boundary = atlas.boundary
        atlas.once["skull_rows"] = SkullRows(skull, atlas.points[boundary.vertices], boundary.modes, boundary.by_node)
    return atlas.once["skull_rows"]
