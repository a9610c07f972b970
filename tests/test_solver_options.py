"""PETSc options pass through under the brainshift_ prefix; failures are named."""

from __future__ import annotations

import pytest

from fenics_brainshift.errors import InputError, SolverError
from fenics_brainshift.runner import Simulation
from fenics_brainshift.scene import scene_from_dict

from conftest import COMM, column_dict

pytestmark = pytest.mark.mpi


def _static(solver: dict):
    scene = scene_from_dict(column_dict(8, solver=solver))
    sim = Simulation(scene, COMM)
    sim.setup()
    return sim


def test_scene_options_reach_the_ksp():
    sim = _static({"kind": "cg-gamg", "options": {"pc_type": "jacobi", "ksp_type": "minres"}})
    assert sim.solves.solver.ksp.getOptionsPrefix() == "brainshift_"
    assert sim.solves.solver.ksp.getType() == "minres"
    assert sim.solves.solver.ksp.getPC().getType() == "jacobi"
    sim.solve_to_settled(0.0)
    assert sim.state.max_displacement() > 0


def test_defaults_per_kind_and_no_leak_from_an_earlier_scene():
    _static({"kind": "cg-gamg", "options": {"pc_type": "jacobi"}})  # must not stick
    gamg = _static({"kind": "cg-gamg"}).solves.solver.ksp.getPC()
    assert gamg.getType() == "gamg"
    assert gamg.getMGSmoother(1).getType() == "chebyshev"  # read at set-up, before the options go
    assert _static({"kind": "cg-jacobi"}).solves.solver.ksp.getPC().getType() == "jacobi"
    direct = _static({"kind": "cholesky"}).solves.solver.ksp
    assert (direct.getType(), direct.getPC().getType()) == ("preonly", "cholesky")
    # CHOLMOD on one rank (its triangular solves are twice as fast here), MUMPS on several
    package = direct.getPC().getFactorSolverType()
    # (Debian's PETSc is built with SuiteSparse on 12 and 13, which name it differently)
    assert package == ("cholmod" if COMM.size == 1 else "mumps")
    if package == "mumps":
        assert direct.getPC().getFactorMatrix().getMumpsIcntl(14) == 100
    assert _static({"kind": "lu"}).solves.solver.ksp.getPC().getFactorSolverType() == "mumps"


def test_a_failed_solve_names_the_reason():
    sim = _static({"kind": "cg-jacobi", "max_it": 2, "rtol": 1e-14})
    with pytest.raises(SolverError, match=r"step solve diverged: DIVERGED_MAX_IT \(-3\) after 2 iterations"):
        sim.solve_to_settled(0.0)


def test_a_factor_package_petsc_lacks_is_bad_input():
    with pytest.raises(InputError, match=r"\[solver\] options: PETSc has no factor package for them \(error 92"):
        _static({"kind": "cholesky", "options": {"pc_factor_mat_solver_type": "no-such-package"}})


@pytest.mark.parametrize(
    "options, message",
    [
        ({"ksp_max_it": "many"}, r"\[solver\] options: PETSc could not read them"),
        ({"ksp_bogus_option": 1}, r"PETSc used none of ksp_bogus_option with kind = \"cg-gamg\""),
        ({"pc_hypre_boomeramg_P_max": 2}, r"PETSc used none of pc_hypre_boomeramg_P_max"),  # another kind's option
    ],
)
def test_malformed_or_unused_options_are_bad_input(options, message):
    with pytest.raises(InputError, match=message):
        _static({"kind": "cg-gamg", "options": options})


def test_viewers_read_only_at_solve_time_are_accepted():
    sim = _static({"kind": "cholesky", "options": {"ksp_converged_reason": True}})
    sim.solve_to_settled(0.0)


def test_cg_hypre_gives_the_direct_answer():
    direct, amg = _static({"kind": "cholesky"}), _static({"kind": "cg-hypre", "rtol": 1e-12})
    for sim in (direct, amg):
        sim.solve_to_settled(0.0)
    assert amg.solves.solver.ksp.getPC().getType() == "hypre"
    assert 0 < amg.solves.iterations[-1] < 50
    assert amg.state.max_displacement() == pytest.approx(direct.state.max_displacement(), rel=1e-9)
