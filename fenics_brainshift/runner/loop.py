"""The one loop of a run: advance (a time step, or the next settled state), record, write;
a guard that fires restores the last good state, which is recorded and written before the
error goes on."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import Interrupted, SolverError
from ..logs import get_logger
from ..outputs.progress import progress
from ..outputs.validity import StrainReport
from .plan import settled_times

log = get_logger("run")


@dataclass
class History:
    """What was recorded at each step or settled state."""

    times: list[float] = field(default_factory=list)
    levels: list[float] = field(default_factory=list)
    probes: list[np.ndarray] = field(default_factory=list)
    surfaces: list[np.ndarray] = field(default_factory=list)
    step_seconds: list[float] = field(default_factory=list)
    strain: StrainReport = field(default_factory=StrainReport)  # the worst over the output times

    def record(self, sim) -> None:
        self.times.append(sim.t)
        self.levels.append(np.nan if sim.level is None else sim.level)
        self.probes.append(sim.probe_values())
        self.surfaces.append(sim.surfaces.values())

    def measure_strain(self, sim) -> None:
        """The strain, rotation and inverted cells of the current state (at output times: a
        DG0 interpolation and a small eigenproblem per cell)."""
        pressed = sim.contact.pressed_dofs(sim.state.u) if sim.contact is not None else None
        self.strain = self.strain.worse(sim.strain_meter.measure(pressed))


def events(sim) -> list[tuple[float, bool]]:
    """(time, write?) of each advance: every time step with XDMF output every [output]
    interval and at the last step; or each breakpoint of the fluid schedule, all written."""
    scene = sim.scene
    if not sim.is_dynamic:
        return [(t, True) for t in static_times(scene)]
    steps, dt, interval = scene.time.steps, scene.time.dt, scene.output.interval
    out, next_write = [], interval
    for n in range(1, steps + 1):
        t = n * dt
        write = n == steps or t >= next_write - 1e-9 * dt
        if write and interval > 0:
            next_write += max(interval, dt)
        out.append((t, write))
    return out


def static_times(scene) -> list[float]:
    """Quasi-static solves happen at each breakpoint of the fluid's and the swellings' schedules
    (t = 0 when nothing changes)."""
    return settled_times(scene)


def march(sim, writer=None) -> tuple[History, SolverError | None]:
    """Run the plan's events on a set-up Simulation; returns the history and the guard's
    error if one fired (the state is then the last good one)."""
    h = History()
    write = writer.write if writer is not None else (lambda *args: None)
    stopped, written = None, None
    if sim.is_dynamic:  # the initial state
        h.record(sim)
        write(sim.t, sim.u, sim.state.v)
        written = sim.t
    plan = events(sim)
    bar = progress(plan, sim.scene.name, total=len(plan))
    snapshot = sim.state.snapshot()
    try:
        for n, (t, due) in enumerate(bar, start=1):
            snapshot = sim.state.snapshot()
            t0 = time.perf_counter()
            its = sim.step() if sim.is_dynamic else sim.solve_to_settled(t)
            h.step_seconds.append(time.perf_counter() - t0)
            h.record(sim)
            if due:
                write(sim.t, sim.u, sim.state.v)
                h.measure_strain(sim)
                written = sim.t
            bar.set_postfix_str(
                f"t={sim.t:.2f} s level={_level(sim.level)} {h.step_seconds[-1] * 1e3:.0f} ms/step", refresh=False
            )
            if not sim.is_dynamic or n % max(1, len(plan) // 10) == 0 or n == len(plan):
                log.info(
                    "  t=%.3f s  level=%s  its=%d  follower iterations=%d  |u|max=%.3e m",
                    sim.t,
                    _level(sim.level),
                    its,
                    sim.follower_iterations,
                    sim.state.max_displacement(),
                )
    except (SolverError, KeyboardInterrupt) as exc:  # keep the last good state, then say why
        stopped = exc if isinstance(exc, SolverError) else Interrupted("interrupted (Ctrl-C)")
        sim.restore(snapshot)
        if not h.times or h.times[-1] != sim.t:
            h.record(sim)
        if written != sim.t and (sim.is_dynamic or not h.step_seconds):
            write(sim.t, sim.u, sim.state.v)
            h.measure_strain(sim)
    finally:
        bar.close()
    return h, stopped


def _level(level) -> str:
    return "dry" if level is None else f"{level:.4f} m"
