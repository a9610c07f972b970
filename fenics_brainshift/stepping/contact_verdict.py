"""What the skull says of how a contact Newton solve ended: settled though |R| stays above its
target (Newton's step from there would move no node by more than a share of the contact's
tolerance), or, where it was not found, the message's part about the skull."""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from ..logs import get_logger

log = get_logger("newton")

# a Newton solve that would fail (no descent; its watchdog's or all its iterations spent) has settled
# when Newton's own step from there (the tangent's answer to the residual left, the skull's hold of
# the pressed nodes in it) would move no node by more than this share of [skull] tolerance along any
# axis: an absolute bound on Newton's correction, asked only where the residual's target cannot be
# met. A node pressed where the skull's facets meet (the distance's gradient turns there) can hold |R|
# where no step lowers it, or lowers it by a percent an iteration, Newton's step from there a few
# micrometres: the synthetic operations of benchmarks/prepare_cases.py --chain exited 3 so at 551fbbc
# (docs/limits.md; summary.json's skull_contact.settled_largest_step_m records the largest let settle).
# Its limits: at a pressed node the penalty's stiffness is in the tangent, so a force error there
# shows as a step of about R / k_pen; and where no step descends the linearisation is poor, so the
# step bounds the distance to equilibrium only roughly.
SETTLED_MOVE = 0.2


class SettledMeasure:
    """Is the state settled though its residual is not at its target: does Newton's step from
    it (a PETSc Vec, or the local array) move no dof by more than SETTLED_MOVE x the contact's
    tolerance, on every rank? Counts the states it let settle."""

    def __init__(self, tolerance: float, comm):
        self.limit, self.comm = SETTLED_MOVE * tolerance, comm
        self.settled = 0
        self.largest_settled = 0.0  # the largest step of a state let settle (m)

    def __call__(self, step) -> bool:
        local = step.getArray(readonly=True) if isinstance(step, PETSc.Vec) else np.asarray(step)
        mine = float(np.abs(local).max(initial=0.0))
        largest = self.comm.allreduce(mine if np.isfinite(mine) else np.inf, op=MPI.MAX)  # (MAX drops a NaN)
        if not largest <= self.limit:
            log.debug("  Newton: stuck, its step would move a node by %.3g um: not settled", largest * 1e6)
            return False
        self.settled += 1
        self.largest_settled = max(self.largest_settled, largest)
        log.debug("  Newton: stuck, its step moves no node by more than %.3g um: settled", largest * 1e6)
        return True


def deepest(contact, u, comm) -> float | None:
    """How far the deepest node is past the skull at u (None without contact, or where u is
    not finite)."""
    if contact is None:
        return None
    if not comm.allreduce(bool(np.isfinite(u.x.array).all()), op=MPI.LAND):
        return None
    return contact.penetration(u)


def contact_note(contact, deepest: float | None) -> str:
    """The skull's part in a settled state that was not found, for its message."""
    if contact is None:
        return ""
    where = "" if deepest is None else f"the deepest node {deepest:.3g} m past the skull where Newton stopped, "
    if deepest is not None and deepest <= contact.tolerance:  # not the tolerance: the skull's shape
        advice = (
            "the deepest node is within it, a looser one will not help; the skull's shape where the "
            "body presses it may be the cause, docs/limits.md"
        )
    else:
        advice = "if the body is held, a looser tolerance may settle"
    return f"; with skull contact: {where}[skull] tolerance = {contact.tolerance:g} m ({advice})"
