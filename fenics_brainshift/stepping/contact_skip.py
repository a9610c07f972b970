"""Settled states of a linear model with a skull, without contact while nothing reaches it.

The contact-free answer (the fast fixed point of static.py, one factor of K) is the exact
answer as long as no surface node ends up past the skull. So each settled state is solved
without contact first; the first one that would pass the skull is solved again, from the
last state that did not, by Newton with contact (newton.py), which then serves the rest of
the run (a body that has reached the skull may stay on it). A body that touches the skull already
at rest (it may rest on it: K alone can be singular) gets contact from the start.
"""

from __future__ import annotations

from ..logs import get_logger

log = get_logger("contact")


class ContactWhenReached:
    def __init__(self, free, make_contact_solver, contact, state):
        self.free, self.make_contact_solver = free, make_contact_solver
        self.contact, self.state = contact, state
        self.engaged = None  # the Newton solver with contact, once a state reaches the skull
        self.skipped = 0  # settled states solved without contact
        self.engaged_at: float | None = None
        self._t_settled: float | None = None
        self._touching = contact.clearance(state.u) <= contact.tolerance  # at rest

    def setup(self) -> None:
        if self._touching:  # K alone may be singular: never factor it
            self.engaged, self.engaged_at = self.make_contact_solver(), self.state.t
            self.engaged.setup()
        else:
            self.free.setup()

    @property
    def contact_rounds(self) -> int:
        return self.engaged.contact_rounds if self.engaged is not None else 0

    @property
    def settled_measure(self):
        return self.engaged.settled_measure if self.engaged is not None else None

    def solve(self, t: float) -> int:
        if self.engaged is None:
            before = self.state.u.x.array.copy()
            its = self.free.solve(t)
            if self.contact.penetration(self.state.u) == 0.0:
                self.skipped += 1
                self._t_settled = t
                return its
            log.info(
                "  t=%g s: the contact-free answer passes the skull by %.3g mm: contact from here on",
                t,
                self.contact.penetration(self.state.u) * 1e3,
            )
            self.state.u.x.array[:] = before
            self.engaged, self.engaged_at = self.make_contact_solver(), t
            self.engaged._t_settled = self._t_settled  # load steps from the last settled state
            self.engaged.adopt_preconditioner(self.free.K)  # K's factor, made for the free solves
            self.free.K = None
        return self.engaged.solve(t)

    def forget_settled(self) -> None:
        self._t_settled = None
        if self.engaged is not None:
            self.engaged.forget_settled()

    def destroy(self) -> None:
        if self.free.K is not None:
            self.free.destroy()
        if self.engaged is not None:
            self.engaged.destroy()
