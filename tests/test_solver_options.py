"""PETSc options pass through under the brainshift_ prefix; failures are named."""
from __future__ import annotations

import pytest
from petsc4py import PETSc

from conftest import COMM, column_dict
from fenics_brainshift.model import build_model
from fenics_brainshift.scene import scene_from_dict
from fenics_brainshift.simulation import Simulation
from fenics_brainshift.solver import SolverError

pytestmark = pytest.mark.mpi


def _static(solver: dict):
    scene = scene_from_dict(column_dict(8, solver=solver))
    sim = Simulation(build_model(scene, COMM))
    sim.setup_static()
    return sim


def test_scene_options_reach_the_ksp():
    sim = _static({"kind": "cg-gamg", "options": {"pc_type": "jacobi", "ksp_type": "minres"}})
    assert sim.solver.ksp.getOptionsPrefix() == "brainshift_"
    assert sim.solver.ksp.getType() == "minres"
    assert sim.solver.ksp.getPC().getType() == "jacobi"
    sim.solve_static(0.0)
    assert sim.max_displacement() > 0


def test_defaults_per_kind_and_no_leak_from_an_earlier_scene():
    _static({"kind": "cg-gamg", "options": {"pc_type": "jacobi"}})  # must not stick
    gamg = _static({"kind": "cg-gamg"}).solver.ksp.getPC()
    assert gamg.getType() == "gamg"
    assert gamg.getMGSmoother(1).getType() == "chebyshev"  # read at set-up, before the options go
    assert _static({"kind": "cg-jacobi"}).solver.ksp.getPC().getType() == "jacobi"
    direct = _static({"kind": "cholesky"}).solver.ksp
    assert (direct.getType(), direct.getPC().getType()) == ("preonly", "cholesky")
    # CHOLMOD on one rank (its triangular solves are twice as fast here), MUMPS on several
    package = direct.getPC().getFactorSolverType()
    if COMM.size == 1 and PETSc.Sys.hasExternalPackage("suitesparse"):
        assert package == "cholmod"
    elif COMM.size > 1:
        assert package == "mumps"
    if package == "mumps":
        assert direct.getPC().getFactorMatrix().getMumpsIcntl(14) == 100
    assert _static({"kind": "lu"}).solver.ksp.getPC().getFactorSolverType() == "mumps"


def test_a_failed_solve_names_the_reason():
    sim = _static({"kind": "cg-jacobi", "max_it": 2, "rtol": 1e-14})
    with pytest.raises(SolverError, match=r"step solve diverged: DIVERGED_MAX_IT \(-3\) after 2 iterations"):
        sim.solve_static(0.0)


def test_a_solver_that_cannot_be_set_up_is_named():
    with pytest.raises(SolverError, match=r"step solver 'cholesky' could not be set up \(PETSc error \d+\): check "
                                          r"\[solver\] options"):
        _static({"kind": "cholesky", "options": {"pc_factor_mat_solver_type": "no-such-package"}})



def test_cg_hypre_gives_the_direct_answer():
    direct, amg = _static({"kind": "cholesky"}), _static({"kind": "cg-hypre", "rtol": 1e-12})
    for sim in (direct, amg):
        sim.solve_static(0.0)
    assert amg.solver.ksp.getPC().getType() == "hypre"
    assert 0 < amg.solver.iterations[-1] < 50
    assert amg.max_displacement() == pytest.approx(direct.max_displacement(), rel=1e-9)
