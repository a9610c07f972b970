"""The small-strain check: largest principal Green-Lagrange strain and rotation, against
homogeneous deformations worked by hand, and the warning a linear run gets past the limit."""

from __future__ import annotations

import numpy as np
import pytest
from dolfinx import fem
from mpi4py import MPI
from scipy.integrate import quad
from scipy.optimize import brentq

from fenics_brainshift import compat
from fenics_brainshift.outputs.validity import STRAIN_LIMIT, StrainMeter
from fenics_brainshift.physics.material import lame_parameters
from fenics_brainshift.runner import run
from fenics_brainshift.runner.build import mesh_from_spec
from fenics_brainshift.scene import MeshSpec, scene_from_dict

from conftest import COMM, column_dict

pytestmark = pytest.mark.mpi
STIFF_PINNED_E = 1.5e5  # Pa: a block hung from three pins strains past 5 % only next to them (8 %)


@pytest.mark.parametrize("degree", [1, 2])
def test_stretch_then_rotation_by_hand(degree):
    """F = R(30 deg about z) diag(1.1, 1, 0.95): E = (diag(1.21, 1, 0.9025) - I) / 2, whose
    eigenvalue of largest magnitude is 0.105, and the rotation is 30 degrees, in every cell."""
    mesh = mesh_from_spec(MeshSpec(shape="box", size=(0.02, 0.03, 0.01), cells=(2, 3, 1)), COMM)
    V = compat.vector_space(mesh, degree)
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    F = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([1.1, 1.0, 0.95])
    u = fem.Function(V)
    u.interpolate(lambda x: (F - np.eye(3)) @ x)  # u = (F - I) X: exact in P1 and P2
    report = StrainMeter(u).measure()
    assert report.strain == pytest.approx(0.105, rel=1e-12)
    assert report.rotation_deg == pytest.approx(30.0, rel=1e-10)
    assert report.inverted == 0 and report.volume_past_limit == pytest.approx(1.0)
    # compression counts as much as tension: diag(0.85, 1, 1.02) has E = -0.13875, 0, 0.0202
    u.interpolate(lambda x: (np.diag([0.85, 1.0, 1.02]) - np.eye(3)) @ x)
    report = StrainMeter(u).measure()
    assert report.strain == pytest.approx(-0.13875, rel=1e-12) and report.volume_past_limit == pytest.approx(1.0)
    # a mirror image (det F = -0.5) turns every cell inside out: all 6 x 5 of them are counted
    u.interpolate(lambda x: (np.diag([-0.5, 1.0, 1.0]) - np.eye(3)) @ x)
    assert StrainMeter(u).measure().inverted == 30


def _column_strain(z: np.ndarray, E: float, nu: float = 0.3, rho: float = 1000.0, H: float = 0.1) -> np.ndarray:
    """The confined column's Green-Lagrange strain at heights z: the linear solution's axial
    strain is e = -rho g (H - z) / (lambda + 2 mu) (P2 holds it exactly), E_zz = e + e^2 / 2."""
    modulus = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    e = -rho * 9.81 * (H - z) / modulus
    return e + e * e / 2


def _cell_centroids_and_volumes(sim):
    from fenics_brainshift.physics.resection import cell_centroids

    mesh = sim.model.mesh
    n = mesh.topology.index_map(3).size_local
    corners = mesh.geometry.x[compat.geometry_dofmap(mesh)[:n]]
    volumes = np.abs(np.linalg.det(corners[:, 1:] - corners[:, :1])) / 6
    return cell_centroids(mesh)[:n], volumes


def test_a_compressed_column_is_measured_against_its_closed_form():
    """The laterally confined column (E = 5 kPa) is compressed by up to 13 % at its foot, in
    bulk: the check reports that strain (it took only the most positive principal strain and
    said 0.1 %), where it is, and the volume past the limit, cell by cell from the closed form."""

    data = column_dict(4, degree=2)
    result = run(scene_from_dict(data))
    validity = result.summary["validity"]
    sim = result.simulation
    z_c, volumes = _cell_centroids_and_volumes(sim)
    exact = _column_strain(z_c[:, 2], 5000.0)
    lowest = COMM.allreduce(float(exact.min(initial=0.0)), op=MPI.MIN)
    assert lowest < -0.12
    assert validity["max_green_lagrange_strain"] == pytest.approx(lowest, rel=1e-6)
    assert validity["max_strain_kind"] == "compression" and validity["max_strain_near"] == "next to a support"
    assert validity["max_strain_at_m"][2] == pytest.approx(0.1 / 16, rel=1e-9)  # the lowest centroid
    past = COMM.allreduce(np.array([volumes[np.abs(exact) > STRAIN_LIMIT].sum(), volumes.sum()]), op=MPI.SUM)
    assert validity["volume_past_limit"] == pytest.approx(past[0] / past[1], rel=1e-12)
    assert validity["volume_past_limit"] > 0.5 and "past 5%" in validity["warning"]
    # a stiff column is within the limit everywhere: no warning, no note
    stiff = run(scene_from_dict(column_dict(4, material={"E": 5e5, "nu": 0.3, "density": 1000.0}))).summary
    assert abs(stiff["validity"]["max_green_lagrange_strain"]) < 5e-3 and stiff["validity"]["volume_past_limit"] == 0
    assert "warning" not in stiff["validity"] and "note" not in stiff["validity"]


def test_a_local_concentration_is_a_note_and_bulk_strain_a_warning():
    """A block hung from three corner nodes: the strain past the limit sits in the few cells
    at the pins (well under 1 % of the volume) - the run is told so in a note, not warned;
    the same block soft enough to strain in bulk is warned."""

    def block(E):
        pins = " or ".join(
            f"(abs(x - {x}) < 1e-9 and abs(y - {y}) < 1e-9 and z < 1e-9)"
            for x, y in ((0.0, 0.0), (0.04, 0.0), (0.0, 0.04))
        )
        return {
            "name": "pinned",
            "mesh": {"shape": "box", "size": [0.04, 0.04, 0.02], "cells": [8, 8, 4]},
            "material": {"E": E, "nu": 0.3, "density": 1000.0},
            "fixed": [{"where": pins}],
            "time": {"mode": "quasi-static"},
            "solver": {"kind": "cholesky"},
        }

    stiff = run(scene_from_dict(block(STIFF_PINNED_E))).summary["validity"]
    assert abs(stiff["max_green_lagrange_strain"]) > STRAIN_LIMIT, stiff
    assert 0 < stiff["volume_past_limit"] <= 0.01 and stiff["max_strain_near"] == "next to a support", stiff
    assert "warning" not in stiff and "local concentration" in stiff["note"]
    soft = run(scene_from_dict(block(STIFF_PINNED_E / 7.5))).summary["validity"]
    assert soft["volume_past_limit"] > 0.01 and "warning" in soft, soft


def test_a_linear_run_past_the_limit_is_reported_and_a_small_one_is_not(shared_tmp):
    soft = column_dict(4, degree=2, material={"E": 30.0, "nu": 0.3, "density": 1000.0})
    summary = run(scene_from_dict(soft)).summary["validity"]
    # e < -1 means det F = 1 + e < 0: the linear column's lower cells are turned inside out
    assert summary["inverted_cells"] > 0 and "inside out" in summary["warning"]
    assert summary["max_green_lagrange_strain"] == pytest.approx(_column_strain(0.1 / 16, 30.0), rel=1e-6)


def test_auto_material_keeps_linear_when_valid_and_switches_when_not():
    stiff = run(
        scene_from_dict(column_dict(4, material={"E": 5e5, "nu": 0.3, "density": 1000.0, "model": "auto"}))
    ).summary
    assert stiff["validity"]["model"] == "linear" and stiff["plan"]["material"].startswith("linear: ")
    # the column compressed by 13 % in bulk: the linear top sag is 9 % off the neo-Hookean
    # 1-D equilibrium, and "auto" now solves the neo-Hookean column
    data = column_dict(16, degree=2, material={"E": 5000.0, "nu": 0.3, "density": 1000.0, "model": "auto"})
    soft = run(scene_from_dict(data)).summary
    assert soft["validity"]["model"] == "neo-hookean" and "of the volume past 5%" in soft["plan"]["material"]
    assert "warning" not in soft["validity"]
    mu, lam = lame_parameters(5000.0, 0.3)
    rho_g, H = 1000.0 * 9.81, 0.1

    def stretch(Z):  # 1-D: P33 = mu (s - 1/s) + lambda ln(s) / s = -rho g (H - Z)
        return brentq(lambda s: mu * (s - 1 / s) + lam * np.log(s) / s + rho_g * (H - Z), 1e-3, 1.0, xtol=1e-15)

    exact = quad(lambda Z: stretch(Z) - 1.0, 0.0, H, epsabs=1e-14, epsrel=1e-12)[0]
    linear = -rho_g * H**2 / (2 * (lam + 2 * mu))
    assert abs(linear - exact) > 0.08 * abs(exact)
    assert soft["probes"]["top"][2] == pytest.approx(exact, rel=1e-4)


def test_removed_cells_are_not_measured():
    """After a resection the strain is measured on the tissue left: u stretches every cell
    by 10 % along z and turns the removed upper half inside out as well (F_zz = -0.4 there);
    the check must see the 10 % everywhere it looks, over the present volume, and no cell
    inside out."""
    mesh = mesh_from_spec(MeshSpec(shape="box", size=(0.02, 0.02, 0.02), cells=(2, 2, 2)), COMM)
    V = compat.vector_space(mesh, 1)
    u = fem.Function(V)
    u.interpolate(lambda x: np.stack([0 * x[0], 0 * x[1], 0.1 * x[2] - 1.5 * np.maximum(x[2] - 0.01, 0.0)]))
    tissue = fem.Function(compat.scalar_space(mesh, "DG", 0))
    from fenics_brainshift.physics.resection import cell_centroids

    tissue.x.array[:] = (cell_centroids(mesh)[:, 2] < 0.01).astype(float)
    report = StrainMeter(u, tissue=tissue).measure()
    assert report.inverted == 0
    assert report.strain == pytest.approx(0.1 + 0.1**2 / 2, rel=1e-12)  # E_zz of F_zz = 1.1
    assert report.volume_past_limit == pytest.approx(1.0, rel=1e-12)  # of the tissue left
    everything = StrainMeter(u).measure()  # without the indicator: the removed half counts
    assert everything.inverted > 0 and everything.strain < -0.4
