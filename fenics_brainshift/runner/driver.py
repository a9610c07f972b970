"""Running a scene end to end: build, step or settle, and (optionally) write.

Every input check happens while building the Simulation and setting up its solver, before
the output folder is created, so bad input leaves no output behind.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mpi4py import MPI

from ..errors import Interrupted, SolverError
from ..logs import get_logger
from ..outputs.files import RunLock, check_writable, clear_run, write_csv, write_json
from ..outputs.fine_surface import SurfaceEmbedding
from ..outputs.xdmf import FieldWriter
from ..scene import Scene
from . import build
from .loop import History, march
from .material_choice import resolve_material
from .simulation import Simulation
from .summary import probe_table, summary

log = get_logger("run")


@dataclass
class Result:
    """What a run returns: the simulation (mesh, model, state), the displacement, the probes'
    final values, the summary (summary.json's content) and the history of every step."""

    simulation: Simulation = field(repr=False)
    summary: dict
    history: History = field(repr=False)
    out: Path | None = None

    @property
    def mesh(self):
        return self.simulation.model.mesh

    @property
    def displacement(self):
        """The final displacement (m), a DOLFINx Function."""
        return self.simulation.u

    @property
    def probes(self) -> dict[str, list[float]]:
        return self.summary["probes"]


def run(
    scene: Scene,
    out: str | Path | None = None,
    comm: MPI.Intracomm = MPI.COMM_WORLD,
    raise_on_stop: bool = True,
    keep: tuple | list = (),
    overwrite: bool = False,
) -> Result:
    """Run a scene. With ``out``, write DIR/summary.json, displacement.xdmf, probes.csv (and the
    fine surface and pictures when the scene asks); without it, write nothing. A guard that
    fires raises SolverError after the last good state is written (raise_on_stop=False: the
    Result says so in summary["status"] instead). An earlier run's files in ``out`` are cleared
    first, but those in ``keep`` (the scene file being run); a folder holding a fit's or an
    update's record is refused, but for the fit's own fitted.toml, unless ``overwrite``
    (outputs/files.py clear_run)."""
    t_start = time.perf_counter()
    out = Path(out) if out is not None else None
    if out is not None:
        check_writable(out, comm)
    scene, material_choice = resolve_material(scene, comm)
    sim = Simulation(scene, comm)
    sim.plan.material = material_choice
    surface = build.fine_surface(scene) if out is not None else None
    embedding = SurfaceEmbedding.of_scene(sim.model.mesh, *surface) if surface is not None else None
    sim.setup()
    writer, lock = None, None
    try:
        if out is not None:
            if comm.rank == 0:
                out.mkdir(parents=True, exist_ok=True)
            comm.barrier()
            lock = RunLock(out, comm)
            clear_run(out, comm, scene.name, keep, overwrite=overwrite)
            _write_skull(sim, out)
            m = sim.model
            writer = FieldWriter(
                out,
                m.mesh,
                m.V,
                scene.output.fields,
                m.constitutive,
                embedding,
                m.tissue.indicator if m.tissue is not None else None,
                sim.contact,
            )
        setup_s = time.perf_counter() - t_start
        _log_start(sim, setup_s)
        h, stopped = march(sim, writer)
        result = Result(sim, summary(sim, h, stopped, setup_s), h, out)
        if "warning" in result.summary["validity"]:
            log.warning("%s: %s", scene.name, result.summary["validity"]["warning"])
        elif "note" in result.summary["validity"]:
            log.info("%s: %s", scene.name, result.summary["validity"]["note"])
        if out is not None:
            writer.close()
            write_csv(out / "probes.csv", *probe_table(sim, h), comm)
            if scene.probes and comm.rank == 0:  # where the probes went, as a Slicer point list (RAS mm)
                from ..images.frames import write_markups

                moved = [1e3 * (np.asarray(p) + result.summary["probes"][k]) for k, p in scene.probes.items()]
                write_markups(out / "probes_final.mrk.json", list(scene.probes), np.array(moved))
            write_json(out / "summary.json", result.summary, comm)
            if scene.output.pictures and stopped is None and comm.rank == 0:
                from ..outputs.pictures import render_in_subprocess

                for path in render_in_subprocess(out):
                    log.info("  wrote %s", path)
            comm.barrier()
        sim.destroy()
    finally:
        if lock is not None:
            lock.release()
    if stopped is not None and raise_on_stop:
        where = f", is in {out}" if out is not None else ""
        if isinstance(stopped, Interrupted):
            raise Interrupted(f"{stopped}; the last good state, t = {sim.t:g} s{where}")
        raise SolverError(f"{stopped} (stopped; the last good state, t = {sim.t:g} s{where})")
    return result


def _write_skull(sim: Simulation, out: Path) -> None:
    """OUT/skull.stl: a skull surface the run used (a file or a label's boundary), as Slicer
    reads models (mm, SPACE=RAS), drawn in deformed.png; a gap skull is the body's own
    surface dilated, with no surface of its own to write."""
    skull = sim.contact.skull if sim.contact is not None else None
    if skull is None or skull.gap is not None or sim.model.comm.rank != 0:
        return
    from ..surfaces.files import write_slicer_stl

    points = skull.triangles.reshape(-1, 3) * 1e3
    write_slicer_stl(out / "skull.stl", points, np.arange(len(points)).reshape(-1, 3))


def _log_start(sim: Simulation, setup_s: float) -> None:
    scene, sizes = sim.scene, sim.model.sizes()
    for line in sim.plan.log_lines():
        log.info(line)
    for line in sim.plan.warnings:
        log.warning("%s: %s", scene.name, line)
    log.info(
        "%s: %d nodes, %d cells, %d dofs, P%d, %s, solver %s, %d rank(s); setup %.2f s",
        scene.name,
        sizes["nodes"],
        sizes["cells"],
        sizes["dofs"],
        scene.element.degree,
        f"{scene.time.scheme} dt={scene.time.dt:g} s" if sim.is_dynamic else "quasi-static",
        scene.solver.kind,
        sim.model.comm.size,
        setup_s,
    )
