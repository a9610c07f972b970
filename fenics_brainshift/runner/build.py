"""From a scene to the plain values the numerics take: the mesh, the model, the solver settings.

The only module besides scene/ that knows the scene's sections; everything it builds takes
arrays, numbers, callables and option dicts.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from dolfinx import fem

from ..errors import InputError
from ..meshing import box_mesh, gmsh_shape, read_mesh_file, voxelized_mesh
from ..meshing.extent import body_diagonal, size_problem
from ..meshing.label_surface import label_surface
from ..meshing.label_volume import labels_at
from ..outputs.fine_surface import load_fine_surface
from ..physics import Cut, FluidSettings, Model, Support
from ..physics.contact import SkullContact
from ..physics.septa import Septum
from ..physics.surface import gathered_outward_surface, surface_facets
from ..scene import Scene
from ..stepping import TimeIntegrator
from ..surfaces.files import SurfaceFileError, read_surface
from ..surfaces.skull import RigidSkull
from ..surfaces.triangles import closed_surface_problem, outward, shell_problem
from ..units import LENGTH_UNITS
from .load_checks import check_loads

if TYPE_CHECKING:
    from mpi4py import MPI


def build_mesh(scene: Scene, comm):
    """The scene's [mesh] as a distributed DOLFINx mesh in metres."""
    return mesh_from_spec(scene.mesh, comm, scene.element.degree)


def mesh_from_spec(spec, comm, degree: int = 1):
    """A [mesh] section (MeshSpec) as a distributed DOLFINx mesh in metres; ``degree`` of the
    run that will use it, for the memory check."""
    if spec.shape == "box" and spec.cells is not None:
        return box_mesh(comm, spec.size, spec.cells, spec.origin, degree)
    if spec.shape is not None:
        return gmsh_shape(comm, spec.shape, spec.size, spec.origin, spec.h, degree)
    if spec.needs_voxels:
        return voxelized_mesh(
            comm,
            spec.file,
            spec.voxel,
            spec.scale,
            spec.fill,
            spec.parts,
            list(spec.labels) if spec.labels else None,
            degree,
        )[0]
    return read_mesh_file(comm, spec.file, spec.scale)


def supports(scene: Scene) -> list[Support]:
    held = [Support(f"[[fixed]] {f.describe()}", _node_selector(scene, f), tuple(f.components)) for f in scene.fixed]
    if scene.skull is not None and scene.skull.glue is not None:  # glued to the skull: held in place
        held.append(Support(f'[skull] fixed_where = "{scene.skull.fixed_where}"', scene.skull.glue, (0, 1, 2)))
    return held


def _node_selector(scene: Scene, region):
    """x (3, N) -> bool (N,) of a [[fixed]] region given by `where` or by `label` (the voxel
    each node lies in)."""
    if region.predicate is not None:
        return region.predicate
    return lambda x: labels_at(scene.mesh.file, np.asarray(x).T, scene.mesh.scale, region.label)


def skull_contact(scene: Scene, model):
    """The [skull] as a SkullContact on the model's surface, or None. A skull file must be a
    closed surface holding the whole body at t = 0; InputError otherwise."""
    if scene.skull is None:
        return None
    spec = scene.skull
    _check_skull_values(scene, model.mesh)
    facets = surface_facets(model.V)
    if spec.gap is not None:
        points, triangles = gathered_outward_surface(facets, model.comm)
        skull = RigidSkull(points, triangles, gap=spec.gap)
    elif spec.label is not None:  # marching cubes of the labels' mask: closed by construction
        skull = RigidSkull(*label_surface(scene.mesh.file, spec.label, scene.mesh.scale))
    else:
        try:
            points, triangles = read_surface(Path(spec.file), scene.mesh.scale)
        except SurfaceFileError as exc:
            raise InputError(f"[skull] file: {exc}") from None
        problem = closed_surface_problem(triangles)
        if problem:
            raise InputError(
                f"[skull] file '{Path(spec.file).name}' is not a closed surface: {problem}; close it "
                f"(e.g. fill holes in 3D Slicer or MeshLab) or use gap = ... instead"
            )
        problem = shell_problem(triangles)
        if problem:
            raise InputError(f"[skull] file '{Path(spec.file).name}': {problem}")
        skull = RigidSkull(points, outward(points, triangles))
    contact = SkullContact(model.V, facets, skull, scene.material.E, spec.tolerance, model.constraints)
    clearance = contact.clearance(fem.Function(model.V))  # at rest
    if spec.file is not None:
        _check_skull_size(scene, skull.triangles.reshape(-1, 3), model.V.mesh, clearance)
    if clearance < -spec.tolerance:
        raise InputError(
            f"[skull] the body's surface is {-clearance * 1e3:.3g} mm past the skull at t = 0: the "
            f"skull must enclose the body (check its unit, [mesh] unit, and its frame)"
        )
    return contact


SKULL_SIZE = (0.5, 5.0)  # a skull file's size over the body's outside this range: a unit slip, not a skull


def _check_body_size(scene: Scene, mesh) -> None:
    """InputError for a body whose size no soft-tissue scene has: a mesh file in another unit
    than [mesh] unit says, named with the unit that would make it a plausible body."""
    problem = size_problem(body_diagonal(mesh), scene.mesh.scale)
    if problem is None:
        return
    what, unit = problem
    spec = scene.mesh
    where = f"[mesh] file '{Path(spec.file).name}'" if spec.file else "[mesh] size"
    hint = (
        f'is it in {unit}? give [mesh] unit = "{unit}"'
        if unit and spec.file
        else "check [mesh] unit and the sizes (metres)"
    )
    raise InputError(f'{where}: {what} with [mesh] unit = "{spec.unit}": {hint}')


def _check_skull_values(scene: Scene, mesh) -> None:
    """[skull] gap and tolerance against the body's size: metres meant as mm are refused."""
    spec, body = scene.skull, body_diagonal(mesh)
    if spec.gap is not None and spec.gap >= 0.5 * body:
        raise InputError(
            f"[skull] gap = {spec.gap:g} m against a {body:.3g} m body: the CSF layer is a few mm "
            f"(gap = 0.003 for 3 mm; metres)"
        )
    limit = min(0.1 * spec.gap if spec.gap is not None else np.inf, 0.01 * body)
    if spec.tolerance > limit:
        raise InputError(
            f"[skull] tolerance = {spec.tolerance:g} m would let the body pass {spec.tolerance * 1e3:g} mm "
            f"into the skull ({limit:.3g} m at most here; metres, default 1e-5)"
        )


def _check_skull_size(scene: Scene, skull_points, mesh, clearance: float) -> None:
    """InputError for a skull file in another unit than the mesh: smaller than half the body
    (by bounding-box diagonal), or more than 5x its size and farther from it at rest than the
    body's own size (a wide box standing in for a floor is fine: the body rests on it)."""
    body = body_diagonal(mesh)
    size = float(np.linalg.norm(skull_points.max(axis=0) - skull_points.min(axis=0)))
    small, large = SKULL_SIZE
    if small * body <= size and (size <= large * body or clearance <= body):
        return
    unit, scale = scene.mesh.unit, scene.mesh.scale
    # the unit that would make it a plausible skull (as large as the body up to 5x)
    guesses = [u for u, f in LENGTH_UNITS.items() if u != unit and body <= size * f / scale <= large * body]
    guess = f"is it in {guesses[0]}? " if guesses else ""
    far = f", {clearance:.3g} m from it at rest" if size > large * body else ""
    raise InputError(
        f"[skull] file '{Path(scene.skull.file).name}' is {size:.3g} m across against a {body:.3g} m "
        f"body{far}: {guess}give the skull in the mesh's unit ({unit}), enclosing the body"
    )


def fluid_settings(scene: Scene) -> FluidSettings | None:
    f = scene.fluid
    if f is None:
        return None
    return FluidSettings(
        density=f.density,
        gravity=scene.gravity.vector,
        rule=f.rule,
        follower=f.follower,
        reuse_tol=f.reuse_tol,
        quadrature_degree=f.quadrature_degree,
        level=f.level,
        volume=f.volume,
        container_area=f.container_area,
        floor=f.floor,
    )


def cuts(scene: Scene) -> list[Cut]:
    """The [[remove]]s as cuts selecting cells by centroid."""
    out = []
    for r in scene.remove:
        if r.predicate is not None:
            select = (lambda predicate: lambda centroids: predicate(centroids.T))(r.predicate)
        else:
            select = (lambda label: lambda centroids: labels_at(scene.mesh.file, centroids, scene.mesh.scale, label))(
                r.label
            )
        out.append(Cut(r.at, r.describe(), select))
    return out


def cell_selector(scene: Scene, region):
    """centroids (N, 3) -> bool (N,) of a region given by `where` or by `label`."""
    if region.predicate is not None:
        return lambda centroids: region.predicate(centroids.T)
    return lambda centroids: labels_at(scene.mesh.file, centroids, scene.mesh.scale, region.label)


def swelling(scene: Scene) -> list:
    """The [[swelling]] regions as (cell selector, t -> volume change) pairs."""
    return [(cell_selector(scene, r), r.at) for r in scene.swelling]


def _check_swelling(scene: Scene, model: Model) -> None:
    """Each [[swelling]] region holds cells (a region that selects none is a unit slip)."""
    if model.growth is None:
        return
    owned = model.mesh.topology.index_map(3).size_local
    for region, (mask, _) in zip(scene.swelling, model.growth.regions):
        if model.comm.allreduce(int(np.count_nonzero(mask[:owned]))) == 0:
            raise InputError(
                f"[[swelling]] {region.describe()} selects no cell of the mesh (cell centroids); "
                f"check the region (metres, mesh frame)"
            )


def septa(scene: Scene) -> list[Septum]:
    """The enabled [[septum]]s as septa on the mesh's frame (m)."""
    out = []
    for spec in scene.septa:
        if spec.normal is not None:
            out.append(Septum.plane(spec.title, spec.point, spec.normal, spec.predicate, spec.reach))
            continue
        if spec.file is not None:
            try:
                points, triangles = read_surface(Path(spec.file), scene.mesh.scale)
            except SurfaceFileError as exc:
                raise InputError(f"[[septum]] {spec.title} file: {exc}") from None
        else:
            points, triangles = label_surface(
                scene.mesh.file, [spec.label], scene.mesh.scale, f"[[septum]] {spec.title} label"
            )
        out.append(Septum.surface(spec.title, points, triangles, spec.predicate, spec.reach))
    return out


def build_model(scene: Scene, comm: MPI.Intracomm, more_cuts: tuple | list = ()) -> Model:
    """Mesh, space, supports, material and loads of a scene; every input check happens here.
    more_cuts: resection.Cuts beside the scene's [[remove]]s (an atlas's resection stages)."""
    mesh = build_mesh(scene, comm)
    _check_body_size(scene, mesh)
    check_loads(scene, mesh)
    mat = scene.material
    model = Model.create(
        mesh,
        scene.element.degree,
        mat.E,
        mat.nu,
        mat.density,
        scene.gravity.vector,
        supports(scene),
        fluid_settings(scene),
        cuts(scene) + list(more_cuts),
        lumped=scene.element.mass == "lumped",
        material_model=mat.model,
        swelling=swelling(scene),
        septa=septa(scene),
    )
    _check_swelling(scene, model)
    return model


def follower_tolerance(scene: Scene, time_step: bool = False) -> float:
    """Where the follower-load fixed-point iteration stops (relative change of u), in a time
    step or a settled state ([fluid] follower_tol, else that one's default)."""
    return scene.fluid.follower_tolerance(time_step) if scene.fluid is not None else 1e-4


def solver_settings(scene: Scene) -> dict:
    """LinearSolver keywords from [solver]."""
    return asdict(scene.solver)


def integrator(scene: Scene) -> TimeIntegrator:
    t = scene.time
    if t.scheme == "newmark":
        return TimeIntegrator.newmark(t.dt)
    return TimeIntegrator.generalized_alpha(t.dt, t.rho_inf)


def fine_surface(scene: Scene):
    """(points m, triangles) of the scene's fine surface, or None; unreadable is InputError."""
    spec = scene.mesh
    try:
        return load_fine_surface(spec.file, spec.surface, spec.scale, spec.labels)
    except InputError as exc:
        raise InputError(f"[mesh] surface: {exc}") from None
