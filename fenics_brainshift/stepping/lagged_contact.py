"""The skull's reaction as one more load of a linear body's time step, so that the step keeps
the contact-free stepper's form: a fixed point of triangular solves with one factor, no
tangent assembled, no Krylov method (dynamic.py, settle.py).

The factor is of A + C (contact_preconditioner.py): A the step's effective matrix, C the
contact stiffness of the nodes pressed when it was built. Each iteration solves

    (A + C) du_{k+1} = b + (1 - alpha_f) f_c(u_n + du_k) + C du_k

with f_c the contact forces at the iterate (physics/contact.py). At the fixed point the C
terms cancel: A du = b + (1 - alpha_f) f_c, the step with contact, exactly. C only sets how
fast it gets there: nodes pressed as when the factor was built cost nothing, the follower
load and the nodes that came or went since are left to Anderson's acceleration, as the
follower load alone is in the contact-free step. The multipliers are then updated and the
step settled again until the contact conditions hold to the tolerance, as with Newton.
"""

from __future__ import annotations

from ..errors import SolverError
from .newton import MAX_CONTACT_ROUNDS


class LaggedContact:
    """contact: a SkullContact; preconditioner: the ContactPreconditioner whose factor the
    step solves with; scale: the step's weight of F_{n+1} (1 - alpha_f)."""

    def __init__(self, contact, preconditioner, scale: float):
        self.contact, self.preconditioner, self.scale = contact, preconditioner, scale
        self.stiffness = preconditioner.stiffness if not preconditioner.factor_is_base() else None
        self.rounds = 0  # multiplier updates in this step

    def add_force(self, F, geometry) -> None:
        """F += the contact forces with the body at ``geometry`` (x + u_n + du)."""
        F.axpy(1.0, self.contact.assemble(geometry))

    def add_lagged(self, rhs, du) -> None:
        """rhs += C du (C: the stiffness in the factor, already weighted by 1 - alpha_f)."""
        if self.stiffness is not None:
            rhs.axpy(1.0, self.contact.times(self.stiffness, du))

    def another_round(self, geometry) -> bool:
        """After the step settled: are the contact conditions off by more than the tolerance?
        Then the multipliers are updated (True: settle again)."""
        off = self.contact.violation(geometry)
        if off <= self.contact.tolerance:
            return False
        if self.rounds == MAX_CONTACT_ROUNDS:
            raise SolverError(
                f"skull contact: the contact conditions are still off by {off * 1e3:.3g} mm "
                f"after {MAX_CONTACT_ROUNDS} multiplier updates"
            )
        self.contact.update_multipliers(geometry)
        self.rounds += 1
        return True
