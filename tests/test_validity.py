"""The small-strain check: largest principal Green-Lagrange strain and rotation, against
homogeneous deformations worked by hand, and the warning a linear run gets past the limit."""
from __future__ import annotations

import numpy as np
import pytest
from dolfinx import fem

from conftest import COMM, column_dict
from fenics_brainshift import compat
from fenics_brainshift.outputs.validity import STRAIN_LIMIT, StrainMeter
from fenics_brainshift.runner import run
from fenics_brainshift.runner.build import mesh_from_spec
from fenics_brainshift.scene import MeshSpec, scene_from_dict

pytestmark = pytest.mark.mpi


@pytest.mark.parametrize("degree", [1, 2])
def test_stretch_then_rotation_by_hand(degree):
    """F = R(30 deg about z) diag(1.1, 1, 0.95): E = (diag(1.21, 1, 0.9025) - I) / 2, whose
    largest eigenvalue is 0.105, and the rotation is 30 degrees, in every cell."""
    mesh = mesh_from_spec(MeshSpec(shape="box", size=(0.02, 0.03, 0.01), cells=(2, 3, 1)), COMM)
    V = compat.vector_space(mesh, degree)
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    F = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([1.1, 1.0, 0.95])
    u = fem.Function(V)
    u.interpolate(lambda x: (F - np.eye(3)) @ x)  # u = (F - I) X: exact in P1 and P2
    strain, rotation, inverted = StrainMeter(u).measure()
    assert strain == pytest.approx(0.105, rel=1e-12)
    assert rotation == pytest.approx(30.0, rel=1e-10)
    assert inverted == 0
    # a mirror image (det F = -0.5) turns every cell inside out: all 6 x 5 of them are counted
    u.interpolate(lambda x: (np.diag([-0.5, 1.0, 1.0]) - np.eye(3)) @ x)
    assert StrainMeter(u).measure()[2] == 30


def test_a_linear_run_past_the_limit_is_reported_and_a_small_one_is_not(shared_tmp):
    soft = column_dict(4, degree=2, material={"E": 30.0, "nu": 0.3, "density": 1000.0})
    summary = run(scene_from_dict(soft)).summary["validity"]
    # the confined column's linear strain is -rho g (H - z) / (lambda + 2 mu), which P2 holds
    # exactly; cells are measured at their centroids, the lowest at z = H / 16 (a tetrahedron
    # with three corners on the floor of a layer H / 4 high); the check reports the
    # Green-Lagrange value -e + e^2 / 2 there
    E, nu, H = 30.0, 0.3, 0.1
    modulus = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    e = 1000.0 * 9.81 * (H - H / 16) / modulus
    assert summary["max_green_lagrange_strain"] == pytest.approx(-e + e * e / 2, rel=1e-6)
    assert summary["max_green_lagrange_strain"] > STRAIN_LIMIT
    assert "neo-hookean" in summary["warning"]
    # e > 1 means det F = 1 - e < 0: the linear column's lower cells are turned inside out
    assert summary["inverted_cells"] > 0 and "inside out" in summary["warning"]
    stiff = run(scene_from_dict(column_dict(4))).summary["validity"]
    assert 0 < stiff["max_green_lagrange_strain"] < 5e-3 and "warning" not in stiff and stiff["inverted_cells"] == 0


def test_auto_material_keeps_linear_when_valid_and_switches_when_not():
    stiff = run(scene_from_dict(column_dict(4, material={"E": 5000.0, "nu": 0.3, "density": 1000.0,
                                                         "model": "auto"}))).summary
    assert stiff["validity"]["model"] == "linear" and stiff["plan"]["material"].startswith("linear: ")
    soft_data = column_dict(4, degree=2, material={"E": 30.0, "nu": 0.3, "density": 1000.0, "model": "auto"})
    soft = run(scene_from_dict(soft_data)).summary
    assert soft["validity"]["model"] == "neo-hookean" and "past 5%" in soft["plan"]["material"]
    assert "warning" not in soft["validity"]
    # the switched run is the neo-Hookean answer itself
    soft_data["material"]["model"] = "neo-hookean"
    direct = run(scene_from_dict(soft_data)).summary
    assert soft["probes"]["top"] == pytest.approx(direct["probes"]["top"], rel=1e-12)
