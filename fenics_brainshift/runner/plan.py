"""What a scene needs, decided once before anything runs, logged, and kept in summary.json.

- Time stepping or not ([time] mode = "auto", the default): a scene with [[remove]] or
  without supports needs inertia (a freed piece, or K singular); otherwise, if every change
  of the fluid level (or volume), and of every region's shrinkage or swelling, takes at least
  ten lowest natural periods, inertia is negligible and the settled states at the schedules'
  breakpoints are solved directly
  (quasi-static: one factor of K, a few solves). The lowest period is estimated as that of a
  shear column of the body's height along gravity, T1 = 4 H / sqrt(G / rho): an order of
  magnitude, which is all the choice needs. "dynamic" or "quasi-static" given explicitly wins.
- Built once and reused: the effective matrix and its factor or preconditioner, the gravity
  vector; the previous step (or breakpoint) is the initial guess.
- The fluid load: reassembled when the level changes, or when the geometry has moved (with
  follower loading) by more than reuse_tol of the largest surface displacement; facets above
  the water are dropped before any arithmetic (hydrostatics).
- Fields: von Mises and velocity only when [output] fields ask for them, at the output
  interval; pictures only when [output] pictures = true, once at the end.
- Stiffness band: with [material] E_sd or G_sd, u scales as 1/E in linear statics, so the band
  for E -/+ sd costs no solve (exact for quasi-static without follower loading; an estimate
  otherwise, marked so).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI

from ..scene import Scene

if TYPE_CHECKING:
    from dolfinx import mesh as dmesh

SLOW_FACTOR = 10.0  # a load change lasting this many lowest periods is quasi-static
# P1 tetrahedra lock as nu nears 0.5: the paper's cube moves 0.90x of P2's at 0.499, 0.71x at
# 0.4999 and 0.02x at 0.4999999 (benchmarks/results/locking.md); the brain's 0.4925 is 0.96x
LOCKING_NU = 0.499


@dataclass
class Plan:
    """What the planner chose for a scene and why: the time mode, the reasons, the periods it
    compared, what is reused between steps, the fluid load, the fields and the material model."""

    mode: str
    reasons: list[str] = field(default_factory=list)
    lowest_period_s: float = 0.0
    fastest_change_s: float | None = None
    reused: str = "effective matrix and its factor/preconditioner, gravity vector; previous answer as initial guess"
    fluid_load: str = ""
    fields: str = ""
    stiffness_band: str = ""
    material: str = ""  # with [material] model = "auto": which model, and why
    contact: str = ""  # with [skull]: when contact is solved, when skipped
    swelling: str = ""  # with [[swelling]]: the regions, and how their growth enters
    septa: str = ""  # with [[septum]]: which, and how they hold the tissue
    warnings: list[str] = field(default_factory=list)  # what the scene may get wrong, logged as warnings

    def as_dict(self) -> dict:
        return asdict(self)

    def log_lines(self) -> list[str]:
        lines = [f"plan: {self.mode} ({'; '.join(self.reasons)})"]
        lines += [f"plan: reuse {self.reused}", f"plan: fluid load {self.fluid_load}", f"plan: {self.fields}"]
        if self.stiffness_band:
            lines.append(f"plan: {self.stiffness_band}")
        if self.material:
            lines.append(f"plan: material {self.material}")
        if self.contact:
            lines.append(f"plan: contact {self.contact}")
        if self.swelling:
            lines.append(f"plan: swelling {self.swelling}")
        if self.septa:
            lines.append(f"plan: septa {self.septa}")
        return lines


def height_along_gravity(mesh, scene: Scene) -> float:
    """The body's extent along gravity (m), global."""
    g = np.asarray(scene.gravity.vector, dtype=float)
    up = -g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 0.0, 1.0])
    h = mesh.geometry.x @ up
    lo = mesh.comm.allreduce(float(h.min()) if len(h) else np.inf, op=MPI.MIN)
    hi = mesh.comm.allreduce(float(h.max()) if len(h) else -np.inf, op=MPI.MAX)
    return hi - lo


def lowest_period(scene: Scene, height: float) -> float:
    mat = scene.material
    return 4.0 * height / np.sqrt(mat.G / mat.density)


def fastest_change(scene: Scene) -> float | None:
    """The shortest duration over which the level (or volume), or a region's shrinkage or
    swelling, changes; 0 for a jump; None when nothing changes (dry and no growth, or constant)."""
    schedules = ([scene.fluid.schedule] if scene.fluid is not None else []) + [r.schedule for r in scene.swelling]
    durations = []
    for schedule in schedules:
        times, values = schedule.times, schedule.values
        durations += [t1 - t0 for t0, t1, v0, v1 in zip(times, times[1:], values, values[1:]) if v1 != v0]
    return min(durations) if durations else None


def settled_times(scene: Scene) -> list[float]:
    """Where settled states are solved: every breakpoint of the fluid's and the swellings'
    schedules (t = 0 when nothing changes)."""
    times = set(scene.fluid.schedule.times if scene.fluid is not None else [0.0])
    for r in scene.swelling:
        times.update(r.schedule.times)
    return sorted(times)


def make_plan(scene: Scene, mesh: dmesh.Mesh) -> Plan:
    """What the scene needs, chosen and explained: the time mode (dynamic or settled states),
    the model, the element, the solver, the step (docs/scenes.md, The plan)."""
    requested = scene.time.mode
    period = lowest_period(scene, height_along_gravity(mesh, scene))
    change = fastest_change(scene)
    reasons = []
    if requested != "auto":
        mode = requested
        reasons.append(f'[time] mode = "{requested}" as asked')
    elif scene.remove:
        mode = "dynamic"
        reasons.append("[[remove]]: a freed piece needs inertia (K alone may be singular)")
    elif not scene.fixed:
        mode = "dynamic"
        reasons.append("no [[fixed]] support: only the mass makes the system solvable")
    elif change is not None and change < SLOW_FACTOR * period:
        mode = "dynamic"
        reasons.append(
            f"the fluid changes within {change:g} s, less than {SLOW_FACTOR:g} lowest periods (T1 ~ {period:.3g} s)"
        )
    else:
        mode = "quasi-static"
        reasons.append(
            "no removal, and the loads change slowly: "
            + (
                "they are constant"
                if change is None
                else f"the fastest change takes {change:g} s, "
                f"at least {SLOW_FACTOR:g} lowest periods (T1 ~ {period:.3g} s)"
            )
        )
        reasons.append("settled states at the schedule's breakpoints, no time stepping")
    fluid = "none (dry)"
    if scene.fluid is not None:
        fluid = "reassembled when the level changes"
        if scene.fluid.follower:
            fluid += (
                f" or the surface has moved by more than {scene.fluid.reuse_tol:g} of its largest "
                f"displacement (follower loading)"
            )
        fluid += "; dry facets skipped"
    wanted = [f for f in scene.output.fields if f != "displacement"]
    fields = (
        "fields: displacement"
        + (f", {', '.join(wanted)}" if wanted else " only (no stresses, no velocity)")
        + (f" every {scene.output.interval:g} s" if scene.output.interval > 0 else " at every output step")
        + ("; pictures at the end" if scene.output.pictures else "; no pictures")
    )
    band = ""
    r = scene.material.relative_sd
    if r is not None:
        exact = mode == "quasi-static" and (scene.fluid is None or not scene.fluid.follower)
        band = (
            f"stiffness band E x (1 -/+ {r:.3g}) from 1/E scaling, no extra solve "
            f"({'exact' if exact else 'an estimate: follower loading or dynamics'})"
        )
    contact = ""
    if scene.skull is not None:
        if mode == "quasi-static" and scene.material.model == "linear":
            contact = (
                "skipped while the contact-free answer stays clear of the skull (then exact); Newton with "
                "contact from the first settled state that would pass it"
            )
        elif mode == "dynamic" and scene.material.model == "linear":
            contact = (
                "the contact-free step's fixed point with the skull's reaction as a lagged load, its factor "
                "updated for the pressed nodes; Newton with contact where that does not settle"
            )
        else:
            contact = "Newton with the contact forces in every " + ("step" if mode == "dynamic" else "settled state")
    growth = ""
    if scene.swelling:
        where = "; ".join(r.describe() for r in scene.swelling)
        growth = f"{len(scene.swelling)} region(s) ({where}): " + (
            "the eigenstrain's load, assembled again when a schedule moves"
            if scene.material.model == "linear"
            else "the growth in the internal force (F = F_e F_g)"
        )
    septa = ""
    if scene.septa:
        septa = (
            f"{len(scene.septa)} ({'; '.join(f'{s.title}: {s.describe()}' for s in scene.septa)}): the "
            f"tissue slides along them; their nodes' normal motion is held exactly (every matrix projected "
            f"once per assembly, P A P + I - P)"
        )
    warnings = []
    if scene.element.degree == 1 and scene.material.nu >= LOCKING_NU:
        warnings.append(
            f"P1 tetrahedra lock at nu = {scene.material.nu:g}: the body comes out too stiff (the paper's "
            f"cube moves 0.71x of P2's at nu = 0.4999, 0.02x at 0.4999999); use [element] degree = 2"
        )
    return Plan(
        mode,
        reasons,
        period,
        change,
        fluid_load=fluid,
        fields=fields,
        stiffness_band=band,
        contact=contact,
        swelling=growth,
        septa=septa,
        warnings=warnings,
    )


def stiffness_band(scene: Scene, plan: Plan, max_displacement: float, probes: dict) -> dict | None:
    """Displacements for E - sd and E + sd from u ~ 1/E (linear statics)."""
    r = scene.material.relative_sd
    if r is None:
        return None
    soft, stiff = 1.0 / (1.0 - r), 1.0 / (1.0 + r)
    return {
        "relative_sd": r,
        "E_Pa": [scene.material.E * (1 - r), scene.material.E, scene.material.E * (1 + r)],
        "exact": plan.mode == "quasi-static" and (scene.fluid is None or not scene.fluid.follower),
        "max_displacement_m": [max_displacement * soft, max_displacement, max_displacement * stiff],
        "probes": {k: [[c * soft for c in v], list(v), [c * stiff for c in v]] for k, v in probes.items()},
    }
