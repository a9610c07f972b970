"""Solving A x = rhs(x) where the right-hand side depends on x through the follower load.

Without follower loading this is one solve. With it, the fluid load F(x + u) makes each
solve a fixed-point problem, iterated with Anderson acceleration (anderson.py) until the
update is below ``tolerance`` of the displacement's size, or until the fluid load was reused
because the surface has not moved (then the map's value is the last solve's answer, exactly).
"""

from __future__ import annotations

from .. import compat
from ..errors import SolverError
from .anderson import AndersonAcceleration

GROWTH = 100.0  # a fixed point with the skull's reaction whose iterate grows this much over its first solve diverges


class Settle:
    """The fixed-point loop around a solver, for one model's supports and fluid load."""

    def __init__(self, template, constraints, fluid, tolerance: float = 1e-4, max_iterations: int = 100):
        self.constraints = constraints  # physics/constraints.py: the supports and septa
        self.fluid = fluid  # a FluidLoad or None
        self.follower = fluid is not None and fluid.follower
        self.tolerance = tolerance  # relative to |u| ([fluid] follower_tol)
        self.max_iterations = max_iterations
        # depth 8, its pairs kept from one time step to the next: fewest solves per step
        self.acceleration = AndersonAcceleration(template)
        self._trial = template.duplicate()
        self.iterations = 0  # of the last call

    def __call__(
        self, x, rhs_for_current_x, solve, t: float, scale: float, same_problem: bool, depends_on_x: bool = False
    ) -> int:
        """Solve for the Function x (its values are the initial guess). ``rhs_for_current_x()``
        assembles the right-hand side for the current x; ``solve(rhs, vec, t)`` solves; scale:
        changes are measured against max(scale, |x|); same_problem: keep the acceleration's
        history (a time step like the last); depends_on_x: the right-hand side depends on x
        through more than the fluid load (the skull's reaction). Returns the Krylov iterations
        of the last solve."""
        x_vec, trial = compat.petsc_vec(x), self._trial
        self.acceleration.reset(keep_history=same_problem)
        its, change, first = 0, float("nan"), None
        for k in range(1, self.max_iterations + 1):
            rhs = rhs_for_current_x()
            if self.follower and not depends_on_x and k > 1 and self.fluid.reused_last:
                trial.copy(x_vec)  # same load as the last solve: its answer is the fixed point
                x.x.scatter_forward()
                break
            self.constraints.vector(rhs)
            x_vec.copy(trial)  # warm start from the current iterate
            its = solve(rhs, trial, t)
            if not (self.follower or depends_on_x):
                trial.copy(x_vec)
                x.x.scatter_forward()
                break
            size = trial.norm()
            first = max(scale, size) if first is None else first
            if depends_on_x and size > GROWTH * first:  # diverging: the rest would only go farther (the skull's
                # distances to iterates metres out cost most of a resection's run; its caller falls back to Newton)
                raise SolverError(
                    f"the fixed point with the skull's reaction diverged at t = {t:g} s (|x| "
                    f"{size / first:.0f} times its first solve's after {k} iterations)"
                )
            change = self.acceleration.update(x_vec, trial) / max(scale, size, 1e-300)
            x.x.scatter_forward()
            if change <= self.tolerance:
                break
        else:
            raise SolverError(
                f"follower-load iteration did not settle in {self.max_iterations} iterations at "
                f"t = {t:g} s (relative change {change:.1e}); use [fluid] follower = false"
            )
        self.iterations = k
        return its
