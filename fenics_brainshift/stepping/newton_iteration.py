"""Newton's iteration on a Function, globalised by a backtracking line search on |R|, with
Eisenstat-Walker forcing and, for contact, a watchdog step. The settled states (newton.py) and
the time steps (newton_dynamic.py) both drive it with their own residual and solve."""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from ..errors import SolverError
from ..logs import get_logger

log = get_logger("newton")


def round_off_floor(K: PETSc.Mat, cell_size: float) -> float:
    """The |R| that round-off alone leaves, whatever the load: a node's internal force sums
    element terms of size (lambda + 2 mu) h^2, each from F, det F and F^-T at J ~ 1 to a
    relative eps (ln J cancels to eps absolute), so |R| ~ eps |K| h (|K| Frobenius, entries ~
    (lambda + 2 mu) h). Measured on the stiff cube (E = 3 GPa, 4 x 4 x 2 cells): 0.13 of this.
    Below it a target cannot be reached: the neo-Hookean cube at E = 3 GPa stopped, its
    target 1e-9 |F| a tenth of the floor."""
    return float(np.finfo(float).eps * K.norm(PETSc.NormType.FROBENIUS) * cell_size)


def newton_iterate(
    x,
    dx,
    residual,
    solve,
    scale,
    rtol: float,
    krylov_floor: float,
    max_iterations: int,
    stall: float = 1.0,
    watchdog: int = 0,
    step_limit=None,
    immaterial=None,
):
    """Newton's iteration on the Function x with a backtracking line search on |R|.

    residual() evaluates R at x into the caller's vector and returns |R| (inf when R is not
    finite); solve(forcing) puts the update -J^-1 R into dx's PETSc vector to the relative
    tolerance ``forcing``; converged when |R| <= rtol scale(), scale() the size of the loads.
    Eisenstat-Walker: the forcing follows |R| / scale() (at most 1e-2, at least the Krylov
    floor and a tenth of the reduction the target still asks for), so the linear solves are no
    more exact than needed and the convergence stays quadratic. A line search that finds no
    descent within ``stall`` x the target counts as converged (round-off: the contact's rounded
    kink, narrower than a micrometre, leaves a floor above 1e-9 of small loads). Otherwise,
    with ``watchdog`` > 0, a step is taken without descent, as far as ``step_limit()`` allows
    (a fraction of dx, no less than the shortest tried), and Newton fails unless the next
    ``watchdog`` iterations bring |R| below where it was (the watchdog technique: Chamberlain,
    Powell, Lemarechal and Pedersen 1982). ``immaterial()``, when given, says whether the
    residual at x (the last evaluated) is too small to matter (the contact's settled measure,
    newton.py): where Newton would fail otherwise (no descent, the watchdog's iterations spent,
    or the iterations while |R| still creeps down), it has converged then. Watchdog and measure
    are for contact: a node off the skull adds nothing to the tangent, so the whole step takes a
    falling body as far past the skull as it would fall, and while the tail of the pressure's
    rounded kink (steep at a tight tolerance) still holds it, each halving of the step only
    halves the distance left, or finds no descent; the step as far as the first node's contact
    lets the next iteration press it. Returns (converged, the |R| history); on failure x is wherever it stopped."""

    def target():
        return rtol * max(scale(), 1e-300)

    def settled() -> bool:  # (it may solve into dx: the step it does not take is kept)
        if immaterial is None:
            return False
        kept = dx.x.array.copy()
        try:
            return immaterial()
        finally:
            dx.x.array[:] = kept

    norm = residual()
    history = [norm]
    watched = None  # (|R|, iteration) where a step was taken without descent
    for iteration in range(max_iterations):
        if norm <= target():
            return True, history
        if watched is not None and norm < (1.0 - 1e-4) * watched[0]:
            watched = None  # the step paid off
        elif watched is not None and iteration - watched[1] > watchdog:
            return settled(), history
        # no more exact than the target needs either: the last solve then takes a few Krylov
        # iterations, not dozens (a tenth of the reduction still left, as a margin)
        forcing = min(1e-2, max(norm / max(scale(), 1e-300), 0.1 * target() / norm, krylov_floor))
        try:
            solve(forcing)
        except SolverError:  # a factor that fails, a solve that diverges with both preconditioners
            return False, history
        dx.x.scatter_forward()
        start = x.x.array.copy()
        for alpha in 0.5 ** np.arange(8):  # backtracking: the full step first
            x.x.array[:] = start + alpha * dx.x.array
            trial = residual()
            if trial < (1.0 - 1e-4 * alpha) * norm:
                break
        else:  # no descent: fine if already at round-off (within ``stall`` targets) or immaterial
            if trial <= stall * target() or (np.isfinite(trial) and settled()):
                return True, history + [trial]
            if not watchdog or watched is not None:
                return False, history
            alpha = max(1.0 if step_limit is None else step_limit(), 0.5**7)
            x.x.array[:] = start + alpha * dx.x.array
            trial, watched = residual(), (norm, iteration)
            if not np.isfinite(trial):
                return False, history
        norm = trial
        history.append(norm)
        log.debug("  Newton: |R| %.3e after a step of %g%s", norm, alpha, " (watched)" if watched else "")
    return norm <= target() or settled(), history
