"""Run-time guards: the energy balance of a dynamic run.

For Newmark's average acceleration the discrete energy obeys, exactly,

    E_{n+1} - E_n = du . (F_n + F_{n+1}) / 2 - du . C (v_n + v_{n+1}) / 2,
    E = 1/2 v.M v + 1/2 u.K u,

so H = E - W, with W the work of the external loads summed by that trapezoid, never grows:
it is constant without damping and falls with it (a resection takes away the removed
tissue's energy). A growing H means energy from nowhere: an unstable step, a wrong load or a
solver that returned garbage. The guard stops the run when H rises above its lowest value by
more than ``tolerance`` times the energy scale seen before the step: 1 % for Newmark (the
identity holds to the solver's tolerance), 100 % for generalized-alpha, whose first steps
overshoot (37 % of the energy at rho_inf = 0, omega dt = 3, measured) while an instability
grows without bound.
(NaN/Inf and diverged Krylov solves are caught where they happen: solves.py and linalg.)
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import SolverError


@dataclass
class EnergyBalance:
    """The energy guard of a dynamic run: H = kinetic + strain energy - the loads' work, step by
    step; H rising above its lowest value by more than ``tolerance`` times the energy scale
    stops the run (energy from nowhere)."""

    tolerance: float = 1e-2
    work: float = 0.0
    lowest: float = float("inf")
    scale: float = 0.0
    history: list[tuple[float, float, float, float]] = field(default_factory=list)  # t, kinetic, strain, work

    def add_work(self, increment: float) -> None:
        self.work += increment

    def check(self, t: float, kinetic: float, strain: float) -> float:
        """Record the state's energies; raise SolverError if H grew. Returns H."""
        h = kinetic + strain - self.work
        self.history.append((t, kinetic, strain, self.work))
        if h > self.lowest + self.tolerance * self.scale and self.scale > 0.0:
            raise SolverError(
                f"energy grew without a source at t = {t:g} s: kinetic + strain - work = {h:.3e} J rose "
                f"{(h - self.lowest) / self.scale:.1%} of the energy scale {self.scale:.3e} J above its "
                f'lowest value; the step is unstable: reduce [time] dt, use scheme = "generalized-alpha" or '
                f"tighten [solver] rtol"
            )
        self.lowest = min(self.lowest, h)
        self.scale = max(self.scale, kinetic + strain + abs(self.work))
        return h
