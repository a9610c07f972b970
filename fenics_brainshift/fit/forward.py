"""The scene's settled state after the drain as a function of the fitted parameters, built
once and re-solved in place.

The mesh, the supports and the factor of K are made once. A new level or head pose changes
only the loads (gravity reassembled, the fluid's up and level); a new G changes no matrix:
with nu fixed the internal force is proportional to G, so the body at G is the body at the
scene's G0 with every load times G0 / G (Model.load_scale) — exact for the linear and the
hyperelastic materials and with skull contact. Each evaluation starts from the last answer
(the follower fixed point or Newton then needs few iterations).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI

from ..errors import SolverError
from ..outputs.fine_surface import SurfaceEmbedding
from ..outputs.points import PointEvaluator
from ..physics.surface import gathered_outward_surface, surface_facets
from ..surfaces.skull import RigidSkull
from ..surfaces.triangles import outward
from .parameters import rotated_gravity

if TYPE_CHECKING:
    from ..scene import Scene

MAX_HALVINGS = 6  # of a parameter change that Newton cannot take at once
# the follower fixed point's stopping point (relative change of u): the Jacobian's differences
# are of relative size 1e-3 (calibrate.DIFFERENCE_STEP), so the answers must be far tighter
FOLLOWER_TOL = 1e-7


class ForwardModel:
    """The scene's settled state re-solved in place for new values of the fitted parameters
    (the level, G, the head's pose): one model and one factorisation for every evaluation."""

    def __init__(self, scene: Scene, comm: MPI.Intracomm = MPI.COMM_WORLD, newton_rtol: float | None = None, cuts=()):
        """newton_rtol: Newton's relative residual for settled states (None: a run's); cuts:
        resection.Cuts made when asked (Simulation.cut_now: an atlas's resection stages)."""
        from ..runner import Simulation, build_model

        if scene.fluid is not None and scene.fluid.follower_tolerance(time_step=False) > FOLLOWER_TOL:
            # finite differences of the residuals need the answers tighter than a run does
            scene = dataclasses.replace(scene, fluid=dataclasses.replace(scene.fluid, follower_tol=FOLLOWER_TOL))
        self.scene = scene
        self.sim = Simulation(scene, comm, model=build_model(scene, comm, cuts) if cuts else None)
        if newton_rtol is not None:
            self.sim.newton_rtol = newton_rtol
        self.sim.setup()
        self.model = self.sim.model
        self.t = scene.settled_time
        self.g0 = np.asarray(scene.gravity.vector, dtype=float)
        self.G0 = scene.material.G
        # the linear material's fixed point starts from the last answer; Newton for finite
        # deformation continues from the last answer through the parameters (it steps loads
        # only in time); with skull contact each evaluation grows its loads from rest
        self.continued = self.model.nonlinear
        self.from_rest = self.sim.contact is not None
        self._last: dict | None = None
        self._scene_level = (
            scene.fluid.level(scene.settled_time) if scene.fluid is not None and scene.fluid.level else 0.0
        )
        self.solves = 0  # settled states computed
        self._located: tuple[np.ndarray, PointEvaluator] | None = None  # the last points and their cells
        fluid = self.model.fluid
        self._facets = fluid.hydro.facets if fluid is not None else surface_facets(self.model.V)
        self._fine = None  # the fine surface, located when first needed (False: the scene has none)

    def heights(self) -> tuple[float, float]:
        """The lowest and highest surface point along up (m): the level's bounds."""
        points, _ = gathered_outward_surface(self._facets, self.model.comm)
        height = points @ (-self.g0 / np.linalg.norm(self.g0))
        return float(height.min()), float(height.max())

    def solve(self, values: dict[str, float]) -> None:
        """The settled state for these parameter values (the others at the scene's)."""
        if self.continued and self._last is not None:  # (on failure the state stays at self._last's)
            self._continue(self._last, dict(values), depth=0)
        else:
            if self.from_rest:
                self.sim.back_to_rest()
            self._apply(values)
            self.sim.solve_to_settled(self.t)
        self._last = dict(values)
        self.solves += 1

    def start_from_rest(self) -> None:
        """The next solve starts from rest, whatever came before (a finite-deformation body too:
        no continuation from the last parameters), so its answer depends on its values alone."""
        self.from_rest = True
        self._last = None
        if self.sim.contact is not None:  # (at rest nothing touches the skull: no pressure carried over)
            self.sim.contact.multipliers = np.zeros_like(self.sim.contact.multipliers)

    def _apply(self, values: dict[str, float]) -> None:
        model = self.model
        g = rotated_gravity(self.g0, values)
        model.gravity.set_gravity(g)
        if model.fluid is not None:
            model.fluid.set_gravity(g)
            if model.fluid.settings.level is not None:  # (the settled state sees only the level at t)
                model.fluid.set_level(values.get("fluid.level", self._scene_level))
        model.load_scale = self.G0 / values.get("material.G", self.G0)

    def _continue(self, start: dict, end: dict, depth: int) -> None:
        """Newton from the state of ``start`` to that of ``end``; if it fails, through the
        parameters' midpoint first (a finite-deformation body: large changes at once may not
        converge, small ones do)."""
        self._apply(end)
        if self.sim.static.solve_from_here(self.t):
            self._last = dict(end)
            return
        if depth == MAX_HALVINGS:
            raise SolverError(
                f"no settled state was found for {end} on the way from {start} (in "
                f"{2**MAX_HALVINGS} steps): the body may have no equilibrium there"
            )
        keys = set(start) | set(end)
        middle = {k: 0.5 * (start.get(k, self._default(k)) + end.get(k, self._default(k))) for k in keys}
        self._continue(start, middle, depth + 1)
        self._continue(middle, end, depth + 1)

    def _default(self, name: str) -> float:
        return {"material.G": self.G0, "fluid.level": self._scene_level}.get(name, 0.0)

    def positions(self, points: np.ndarray) -> np.ndarray:
        """Where pre-operative points (n, 3; m) are in the current state."""
        if self._located is None or not np.array_equal(self._located[0], points):
            self._located = (np.array(points, copy=True), PointEvaluator(self.model.mesh, points))
        return points + self._located[1].values(self.sim.u)

    @property
    def measured_surface(self) -> str:
        """What point-to-surface distances are measured to (fit.json says it)."""
        fine = self._fine_surface()
        if fine is None:
            return "the mesh's boundary (the scene has no fine surface)"
        return f"the fine surface ({len(fine.triangles)} triangles)"

    def _fine_surface(self):
        """The scene's fine surface located in the mesh once, or None: the real cortex's shape,
        where the mesh's boundary (a voxel model's staircase) is up to half a voxel's diagonal
        off it, so points measured on the cortex could not be matched by the right parameters."""
        if self._fine is None:
            from ..runner import build

            fine = build.fine_surface(self.scene)
            self._fine = False if fine is None else SurfaceEmbedding.of_scene(self.model.mesh, fine[0], outward(*fine))
        return self._fine or None

    def signed_distances(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (m, + outside) of points to the current deformed surface: the fine
        surface where the scene has one, else the mesh's boundary."""
        fine = self._fine_surface()
        if fine is not None:
            surface, triangles = fine.points + fine.values(self.sim.u), fine.triangles
        else:
            surface, triangles = gathered_outward_surface(self._facets, self.model.comm, self.sim.u)
        distance, side, _ = RigidSkull(surface, triangles).distance(points)
        return side * distance

    def destroy(self) -> None:
        self.sim.destroy()
