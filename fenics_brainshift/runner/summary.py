"""summary.json and probes.csv of a run: what it computed, how fast, and whether it is valid."""

from __future__ import annotations

import statistics

import numpy as np

from .. import compat, formats
from ..errors import Interrupted
from ..outputs.validity import assessment
from .plan import stiffness_band


def probe_table(sim, h) -> tuple[list[str], list[list[float]]]:
    """probes.csv: header and rows (t, level, probes, surface means)."""
    header = (
        ["t", "level"]
        + [f"{n}_{c}" for n in sim.probes.names for c in "xyz"]
        + [f"{n}_mean_{c}" for n in sim.surfaces.names for c in "xyz"]
    )
    rows = [[t, lv, *p.ravel(), *s.ravel()] for t, lv, p, s in zip(h.times, h.levels, h.probes, h.surfaces)]
    return header, rows


def summary(sim, h, stopped, setup_s: float) -> dict:
    """Every key docs/outputs.md's summary.json row names."""
    scene, model, plan = sim.scene, sim.model, sim.plan
    dynamic = sim.is_dynamic
    its = sim.solves.iterations
    probes = sim.probes.as_dict(h.probes[-1])
    max_u = sim.state.max_displacement()
    out = {
        "scene": scene.name,
        # a mesh from an image (NIfTI / NRRD) is in its RAS frame: pictures label the anatomy
        "frame": "RAS" if scene.mesh.file and formats.is_label_volume(scene.mesh.file) else None,
        "status": "ok"
        if stopped is None
        else "interrupted"
        if isinstance(stopped, Interrupted)
        else f"stopped: {stopped}",
        "dolfinx_version": compat.DOLFINX_VERSION,
        "ranks": model.comm.size,
        **model.sizes(),
        "degree": scene.element.degree,
        "mode": plan.mode,
        "plan": plan.as_dict(),
        "scheme": scene.time.scheme if dynamic else "static",
        "solver": scene.solver.kind,
        "steps": len(h.step_seconds),
        "setup_s": setup_s,
        "step_s_median": statistics.median(h.step_seconds) if h.step_seconds else 0.0,
        "solve_s_total": sim.solves.seconds,
        "linear_solves": sim.solves.count,
        "iterations_mean": float(np.mean(its)) if its else 0.0,
        "iterations_max": int(max(its)) if its else 0,
        "final_time": sim.t,
        "gravity_vector": list(scene.gravity.vector),
        "max_displacement_m": max_u,
        "probes": probes,
        "surfaces": sim.surfaces.as_dict(h.surfaces[-1]),
        **sim.forces(),
        "validity": assessment(h.strain, scene.material.model),
    }
    if dynamic and sim.dynamic is not None:
        e = sim.dynamic.energy
        t, kinetic, strain, work = e.history[-1] if e.history else (sim.t, 0.0, 0.0, 0.0)
        out["energy_J"] = {
            "kinetic": kinetic,
            "strain": strain,
            "external_work": work,
            "balance": kinetic + strain - work,
        }
    if scene.material.relative_sd is not None:
        out["stiffness_band"] = stiffness_band(scene, plan, max_u, probes)
    if model.fluid is not None:
        out["fluid_assemblies"], out["fluid_reuses"] = model.fluid.assemblies, model.fluid.reuses
    if sim.contact is not None:
        solver = sim.dynamic if dynamic else sim.static
        measure = getattr(solver, "settled_measure", None)
        out["skull_contact"] = {
            **sim.contact.report(sim.state.u),
            "multiplier_updates": getattr(solver, "contact_rounds", 0),
            # Newton solves that ended without descent, their step from there moving no node by
            # more than a fifth of the tolerance (stepping/contact_verdict.py SETTLED_MOVE), and
            # the largest such step
            "settled_without_descent": measure.settled if measure is not None else 0,
            "settled_largest_step_m": measure.largest_settled if measure is not None else 0.0,
            "states_without_contact": getattr(solver, "skipped", 0),
            "contact_from_s": getattr(solver, "engaged_at", None),
        }
    if model.constraints.labels:
        out["septa"] = sim.septa_report()
    if model.tissue is not None:
        out["removals"] = sim.removals
        out["removed_fraction"] = model.tissue.removed_fraction
        out["removed_ml"] = (model.tissue.total_volume - model.tissue.volume()) * 1e6
    return out
