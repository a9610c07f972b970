"""theatre/suggest.py: the next point worth touching. Its expected spread at the targets is
the posterior's after that touch's row is added to the fit's problem and the covariance
computed again in full (atlas/posterior.py), not by the rank-one update it uses; no other
candidate lowers it more; the candidates are the exposed cortex."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from mpi4py import MPI

from fenics_brainshift import load_scene
from fenics_brainshift.atlas import posterior
from fenics_brainshift.atlas.build import build
from fenics_brainshift.atlas.locate import MeshLocator
from fenics_brainshift.atlas.prepared import moving_surface
from fenics_brainshift.atlas.scenarios import parse_vary
from fenics_brainshift.atlas.update import update
from fenics_brainshift.images.targets import Target
from fenics_brainshift.theatre.suggest import EXPOSED_RADIUS, FACING_UP, exposed_cortex, suggest

pytestmark = pytest.mark.usefixtures("serial_only")


@pytest.fixture(scope="module")
def atlas():
    built, _ = build(
        load_scene("brain", ["mesh.voxel=0.01", "time.mode=quasi-static"]),
        parse_vary(["fluid.level=0.02,0.03,0.04", "gravity.angle_z=-8,0,8"]),
        MPI.COMM_WORLD,
    )
    return built


def _spread_after(result, atlas, targets, row) -> float:
    """The targets' RMS spread (m) with one more data row, the covariance recomputed in full."""
    p = result.problem
    grown = dataclasses.replace(
        p,
        A=np.vstack([p.A, row]),
        b=np.r_[p.b, row @ result.weights],  # (read where the fit puts it: the scale stays)
        groups=np.r_[p.groups, p.groups.max() + 1],
    )
    free, sigma, dimension = posterior.covariance(grown, result.alpha, result.weights)
    sigma = sigma * posterior.scale(grown, result.weights, dimension)
    index, weight, _ = MeshLocator(atlas.points, atlas.tetrahedra).weights(targets)
    T = np.einsum("nj,mnjd->ndm", weight, atlas.vertex_modes[:, index, :].astype(float)).reshape(-1, len(p.gram))
    T = T[:, free]
    return float(np.sqrt(np.trace(T @ sigma @ T.T) / len(targets)))


def test_the_suggested_touch_lowers_the_targets_spread_most_as_the_full_posterior_says(atlas):
    up = np.array([0.0, 1.0, 0.0])  # (the bundled brain lies supine: gravity along -y)
    centre = atlas.points[np.argmax(atlas.points[:, 1])]
    candidates = exposed_cortex(atlas, centre, up)
    vertices, normals = candidates
    surface = moving_surface(atlas)
    at = surface.at_reference[vertices]
    assert len(vertices) > 20
    assert np.all(np.linalg.norm(at - centre, axis=1) < EXPOSED_RADIUS) and np.all(normals @ up > FACING_UP)
    rng = np.random.default_rng(0)
    touched = rng.choice(vertices, 6, replace=False)
    measured = surface.at_reference[touched] + rng.normal(0.0, 0.3e-3, (6, 3))
    noise = 1e-3
    result = update(atlas, Target(measured, None, [f"s{i}" for i in range(6)]), noise)
    targets = atlas.points[[np.argmin(np.linalg.norm(atlas.points - centre - [0.0, -0.03, 0.0], axis=1))]]
    s = suggest(atlas, result, targets, candidates, noise)
    assert s is not None and s.vertex in vertices and 0 < s.expected < s.spread

    def row(v):  # a touch at vertex v: the distance along its normal, noise-weighted as the fit's rows
        k = list(vertices).index(v)
        return normals[k] @ surface.by_vertex[v].astype(float)

    before = _spread_after(result, atlas, targets, np.zeros(len(result.weights)))
    assert s.spread == pytest.approx(before, rel=1e-9)
    assert s.expected == pytest.approx(_spread_after(result, atlas, targets, row(s.vertex)), rel=1e-6)
    others = rng.choice(vertices, 25, replace=False)
    assert all(_spread_after(result, atlas, targets, row(v)) >= s.expected * (1 - 1e-9) for v in others)
