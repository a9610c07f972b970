"""What the skull says of how a contact Newton solve ended: settled though |R| stays above its
target (the residual left would move no node by more than a share of the contact's tolerance),
or, where it was not found, the message's part about the skull."""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from ..logs import get_logger

log = get_logger("newton")

# a Newton solve that would fail (no descent; its watchdog's or all its iterations spent) has settled
# when the residual left would move no node by more than this share of [skull] tolerance under the
# node's own stiffness (|R_i| / K_ii): a node pressed where the skull's facets meet (the distance's
# gradient turns there) can hold |R| where no step lowers it, or lowers it by a percent an iteration
# (the chris_t1 case of benchmarks/prepare_cases.py --chain: exit 3 before, docs/limits.md)
SETTLED_MOVE = 1e-2


class SettledMeasure:
    """Is a residual R immaterial: would it move no node by more than SETTLED_MOVE x the
    contact's tolerance under the node's own stiffness (K_ii, K with supports: 1 on their rows,
    where R is 0)? The largest over every rank. Counts the residuals it let settle."""

    def __init__(self, K: PETSc.Mat, tolerance: float, comm):
        self.diagonal, self.limit, self.comm = K.getDiagonal(), SETTLED_MOVE * tolerance, comm
        self.settled = 0

    def __call__(self, R: PETSc.Vec) -> bool:
        move = np.abs(R.getArray(readonly=True)) / np.abs(self.diagonal.getArray(readonly=True))
        largest = self.comm.allreduce(float(move.max(initial=0.0)), op=MPI.MAX)
        if largest > self.limit:
            return False
        self.settled += 1
        log.debug("  Newton: stuck, the residual moves no node by more than %.3g um: settled", largest * 1e6)
        return True

    def destroy(self) -> None:
        self.diagonal.destroy()


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
