"""How one mode of an atlas is settled from its neighbours: a swelling mode from the prior
state, a drain/pose mode from the last one (with the skull, from the last two extrapolated in
the level), and from rest where that does not settle (atlas/build.py deals them)."""

from __future__ import annotations

import numpy as np

from ..errors import SolverError
from ..logs import get_logger

log = get_logger("fenics_brainshift.atlas.build")  # (the atlas build's log, as before the split)


def solve_from_prior(forward, values: dict, prior_u: np.ndarray, prior_multipliers) -> None:
    """The settled state of a swelling mode, Newton from the prior state (its multipliers too):
    the mode is the change the swelling makes there. With the skull the equilibrium need not be
    unique where its inner surface is concave (the anterior fossa): on the 5 mm brain, 3 mm gap,
    the whole brain shrunk 4 % from rest and from the prior settle up to 6.55 mm apart (0.20 mm on
    average; benchmarks/results/skull_atlas.md). A linear body with the skull whose Newton fails
    from there is solved again from rest; otherwise the failure stands (from rest a neo-Hookean
    body continues from its last state all the same, and without the skull the fixed point is the
    same from any start)."""
    forward.sim.u.x.array[:] = prior_u
    contact = forward.sim.contact
    if prior_multipliers is not None:
        contact.multipliers = prior_multipliers.copy()
    forward.from_rest = False
    try:
        forward.solve(values)
    except SolverError as exc:
        if contact is None or forward.continued:
            raise
        log.info("atlas: a swelling mode from the prior state did not settle (%s); solving it from rest", exc)
        forward.from_rest = True
        forward.solve(values)


def predict_start(forward, last: list, values: dict) -> None:
    """Newton's start for the next level of a pose with the skull: the last two settled states
    (and their contact multipliers) extrapolated linearly in the level, not the last state
    alone. The level's change then needs no halved first steps: on the 5 mm brain, 3 mm gap,
    13 levels at one pose, 5.5 Newton iterations a state against 6.2 from the last state.
    Where the equilibrium is not unique (the skull's concave parts) the state reached may
    differ from the last state's by about the contact's tolerance (MODE_TOLERANCE; 0.074 mm
    at most there): both are settled and inside the skull to it
    (benchmarks/results/skull_atlas.md)."""
    (level_0, u_0, m_0), (level_1, u_1, m_1) = last
    level = values.get("fluid.level")
    if level is None or level_0 is None or level_1 == level_0:
        return
    ratio = (level - level_1) / (level_1 - level_0)
    if not 0.0 < ratio <= 2.0:  # (a jump back, or far ahead: the last state is the better start)
        return
    forward.sim.u.x.array[:] = u_1 + ratio * (u_1 - u_0)
    multipliers = m_1 + ratio * (m_1 - m_0)  # pressure vectors: one turned past zero is none
    multipliers[np.einsum("ni,ni->n", multipliers, m_1) <= 0.0] = 0.0
    forward.sim.contact.multipliers = multipliers


def solve_family_mode(forward, values: dict) -> None:
    """A drain/pose mode, from the last mode (or from rest, as forward.from_rest says). With the
    skull, one that does not settle from the last mode is solved again from rest: Newton's path
    from the last contact state can stall where the path from rest, along which the loads grow,
    does not (the default atlas at 10 mm with a 3 mm gap, when the contact's multiplier was a
    scalar: head turned -12 and 6 degrees, the level from 45 to 50 mm). A failure
    from rest stands (the caller may leave the mode out)."""
    try:
        forward.solve(values)
    except SolverError as exc:
        if forward.sim.contact is None or forward.from_rest or forward.continued:
            raise
        log.info("atlas: %s did not settle from the last mode (%s); solving it from rest", values, exc)
        forward.from_rest = True
        forward.solve(values)
