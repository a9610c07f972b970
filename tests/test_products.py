"""The fast paths of a dynamic step give the same numbers as the plain ones."""

from __future__ import annotations

import numpy as np
import pytest

from fenics_brainshift.linalg import PairProduct
from fenics_brainshift.runner import Simulation, build_model
from fenics_brainshift.scene import scene_from_dict

from conftest import COMM, column_dict

pytestmark = pytest.mark.mpi


def _model(**sections):
    return build_model(scene_from_dict(column_dict(6, time={"mode": "dynamic"}, **sections)), COMM)


def test_pair_product_equals_two_matrix_vector_products():
    model = _model()
    K = model.assemble(model.stiffness_form(), with_bcs=False)
    x1, x2 = K.createVecRight(), K.createVecRight()
    x1.setRandom()
    x2.setRandom()
    y1, y2, ref1, ref2 = (K.createVecLeft() for _ in range(4))
    pair = PairProduct(K)
    for _ in range(2):  # the second call reuses the product's storage
        pair.multiply(x1, x2, y1, y2)
        K.mult(x1, ref1)
        K.mult(x2, ref2)
        for y, ref in ((y1, ref1), (y2, ref2)):
            y.axpy(-1.0, ref)
            assert y.norm() <= 1e-14 * ref.norm()
        x1.scale(-2.0)
    pair.destroy()


def test_lumped_mass_is_kept_as_its_diagonal_only():
    model = _model()
    assembled = model.assemble(model.mass_form(), with_bcs=False)
    M = model.mass_matrix()
    assert M.getInfo()["nz_used"] == M.getSize()[0]  # one entry per row, globally summed
    d = M.getDiagonal()
    d.axpy(-1.0, assembled.getDiagonal())
    assert d.norm() == 0.0
    x, y, ref = M.createVecRight(), M.createVecLeft(), M.createVecLeft()
    x.setRandom()
    M.mult(x, y)
    assembled.mult(x, ref)  # the assembled lumped matrix carries only zeros off the diagonal
    y.axpy(-1.0, ref)
    assert y.norm() <= 1e-14 * ref.norm()


def test_consistent_mass_stays_a_full_matrix():
    model = _model(element={"mass": "consistent"})
    M = model.mass_matrix()
    assert M.getInfo()["nz_used"] > 3 * M.getSize()[0]


def test_energy_check_shares_the_next_right_hand_side_product():
    """The guard's K u and the next step's K w_k come from one product; a step that finds
    it must give the same state as one that computes K w_k itself."""
    scene = scene_from_dict(column_dict(6, time={"mode": "dynamic"}))
    sims = [Simulation(scene, COMM) for _ in range(2)]
    for sim in sims:
        sim.setup()
    sims[1].dynamic.check_energy = False  # no guard: each step computes K w_k itself
    for _ in range(5):
        for sim in sims:
            sim.step()
    a, b = (s.u.x.array for s in sims)
    assert np.abs(a - b).max() <= 1e-12 * np.abs(a).max()
    assert np.abs(a).max() > 0
