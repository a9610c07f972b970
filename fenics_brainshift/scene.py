"""A scene: everything a run needs, as small validated dataclasses loaded from TOML.

Units are SI (m, kg, s, Pa) everywhere; only a mesh *file* may be given in other length units
(``[mesh] unit = "mm"``), and it is scaled to metres on load. Every check raises SceneError
with a one-line message that names the field (``[material] E``) and says what would fix it.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from .regions import Predicate, PredicateError, parse_predicate


class SceneError(ValueError):
    """Bad scene input. The message is one line and names the field."""


# ---------------------------------------------------------------- small checks
def _number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SceneError(f"{where} must be a finite number (got {value!r})")
    return float(value)


def _positive(where: str, value: Any) -> float:
    value = _number(where, value)
    if value <= 0:
        raise SceneError(f"{where} must be > 0 (got {value:g})")
    return value


def _non_negative(where: str, value: Any) -> float:
    value = _number(where, value)
    if value < 0:
        raise SceneError(f"{where} must be >= 0 (got {value:g})")
    return value


def _vector3(where: str, value: Any) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise SceneError(f"{where} must be a list of 3 numbers such as [0, 0, -9.81] (got {value!r})")
    return tuple(_number(f"{where}[{i}]", v) for i, v in enumerate(value))  # type: ignore[return-value]


def _choice(where: str, value: Any, options: tuple[str, ...]) -> str:
    if value not in options:
        raise SceneError(f"{where} must be one of {', '.join(options)} (got {value!r})")
    return value


def _integer(where: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise SceneError(f"{where} must be an integer >= {minimum} (got {value!r})")
    return value


# ---------------------------------------------------------------- sections
LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
SHAPES = ("box", "ellipsoid")


@dataclass(slots=True)
class MeshSpec:
    """A gmsh built-in shape or a mesh file.

    box: ``size`` = extents, ``origin`` = lowest corner; ``cells`` = [nx, ny, nz] gives a
    structured grid of hexahedra split into five tetrahedra each (the paper's cube grids),
    ``h`` gives an unstructured gmsh mesh of that element size.
    ellipsoid: ``size`` = semi-axes, ``origin`` = centre, ``h`` = element size.
    file: .msh (gmsh) or .xdmf (DOLFINx/meshio) tetrahedral mesh, or a segmentation to be
    voxel-meshed (the paper's embedding method): a label volume (.nii, .nii.gz) or a surface
    (.stl, .obj, .ply, .vtk, .vtp, .gii, ...) with ``voxel`` (m), ``fill``, ``parts`` and
    ``labels``; coordinates in ``unit``. ``surface``: a fine surface (same unit) that follows
    the coarse model and is written deformed; a surface input is its own by default.
    """

    shape: str | None = None
    file: str | None = None
    size: tuple[float, float, float] = (0.05, 0.05, 0.025)
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    cells: tuple[int, int, int] | None = None
    h: float | None = None
    unit: str = "m"
    voxel: float | None = None
    fill: float = 0.5
    parts: int = 1
    labels: tuple[int, ...] | None = None
    surface: str | None = None

    def __post_init__(self):
        if (self.shape is None) == (self.file is None):
            raise SceneError("[mesh] give exactly one of shape = \"box\" or file = \"mesh.msh\"")
        if self.shape is not None:
            _choice("[mesh] shape", self.shape, SHAPES)
        self.size = _vector3("[mesh] size", self.size)
        for i, s in enumerate(self.size):
            _positive(f"[mesh] size[{i}]", s)
        self.origin = _vector3("[mesh] origin", self.origin)
        if self.cells is not None:
            if not isinstance(self.cells, (list, tuple)) or len(self.cells) != 3:
                raise SceneError(f"[mesh] cells must be [nx, ny, nz] (got {self.cells!r})")
            self.cells = tuple(_integer(f"[mesh] cells[{i}]", c, 1) for i, c in enumerate(self.cells))
        if self.h is not None:
            self.h = _positive("[mesh] h", self.h)
        if self.shape == "box" and (self.cells is None) == (self.h is None):
            raise SceneError("[mesh] a box needs either cells = [nx, ny, nz] or h = element size")
        if self.shape == "ellipsoid" and self.h is None:
            raise SceneError("[mesh] an ellipsoid needs h = element size (m)")
        _choice("[mesh] unit", self.unit, tuple(LENGTH_UNITS))
        if self.voxel is not None:
            self.voxel = _positive("[mesh] voxel", self.voxel)
        self.fill = _number("[mesh] fill", self.fill)
        if not 0.0 <= self.fill <= 1.0:
            raise SceneError(f"[mesh] fill must be in [0, 1] (got {self.fill:g}); 0 keeps every voxel the object touches")
        self.parts = _integer("[mesh] parts", self.parts, 1)
        if self.labels is not None:
            if not isinstance(self.labels, (list, tuple)) or not all(isinstance(v, int) and not isinstance(v, bool) for v in self.labels):
                raise SceneError(f"[mesh] labels must be a list of integers (got {self.labels!r})")
            self.labels = tuple(self.labels)
        if self.file is not None and self.needs_voxels and self.voxel is None:
            raise SceneError(f"[mesh] file '{Path(self.file).name}' is a segmentation: give voxel = size in m (e.g. 0.005)")
        if self.surface is not None and not isinstance(self.surface, str):
            raise SceneError("[mesh] surface must be a file name")

    @property
    def scale(self) -> float:
        return LENGTH_UNITS[self.unit]

    @property
    def needs_voxels(self) -> bool:
        name = str(self.file).lower()
        return not (name.endswith(".msh") or name.endswith(".xdmf"))


@dataclass(slots=True)
class Material:
    """Linear elastic: E and nu, or G (shear modulus) and nu; density in kg/m3. ``E_sd`` or
    ``G_sd``: the modulus's standard deviation, for the stiffness band in summary.json."""

    nu: float = 0.45
    density: float = 1000.0
    E: float | None = None
    G: float | None = None
    E_sd: float | None = None
    G_sd: float | None = None

    def __post_init__(self):
        if (self.E is None) == (self.G is None):
            raise SceneError("[material] give exactly one of E (Young's modulus, Pa) or G (shear modulus, Pa)")
        self.nu = _number("[material] nu", self.nu)
        if not -1.0 < self.nu < 0.5:
            raise SceneError(f"[material] nu must be in (-1, 0.5) (got {self.nu:g}); 0.5 is incompressible, use 0.4999 at most")
        self.density = _positive("[material] density", self.density)
        if self.G is not None:
            self.G = _positive("[material] G", self.G)
            self.E = 2.0 * self.G * (1.0 + self.nu)
        else:
            self.E = _positive("[material] E", self.E)
            self.G = self.E / (2.0 * (1.0 + self.nu))
        if self.E_sd is not None and self.G_sd is not None:
            raise SceneError("[material] give at most one of E_sd or G_sd")
        for key, modulus in (("E_sd", self.E), ("G_sd", self.G)):
            sd = getattr(self, key)
            if sd is not None:
                sd = _positive(f"[material] {key}", sd)
                if sd >= modulus:
                    raise SceneError(f"[material] {key} = {sd:g} must be below the modulus ({modulus:g}): "
                                     f"the band's soft end would have no stiffness")
                setattr(self, key, sd)

    @property
    def relative_sd(self) -> float | None:
        """The modulus's relative standard deviation (the same for E and G at fixed nu)."""
        if self.E_sd is not None:
            return self.E_sd / self.E
        return self.G_sd / self.G if self.G_sd is not None else None

    @property
    def mu(self) -> float:
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def lmbda(self) -> float:
        return self.E * self.nu / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))


@dataclass(slots=True)
class Gravity:
    vector: tuple[float, float, float] = (0.0, 0.0, -9.81)

    def __post_init__(self):
        self.vector = _vector3("[gravity] vector", self.vector)

    @property
    def magnitude(self) -> float:
        return math.sqrt(sum(c * c for c in self.vector))

    @property
    def up(self) -> tuple[float, float, float]:
        g = self.magnitude
        return tuple(-c / g for c in self.vector)  # type: ignore[return-value]


class Schedule:
    """Piecewise linear in time: points (t, value), held constant before the first and after
    the last. A single number means constant."""

    __slots__ = ("points", "where")

    def __init__(self, points, where: str):
        self.where = where
        if isinstance(points, (int, float)) and not isinstance(points, bool):
            points = ((0.0, float(points)),)
        if not isinstance(points, (list, tuple)) or not points:
            raise SceneError(f"{where} must be a number or a list of [time, value] pairs")
        pts = []
        for i, p in enumerate(points):
            if not isinstance(p, (list, tuple)) or len(p) != 2:
                raise SceneError(f"{where}[{i}] must be a [time, value] pair (got {p!r})")
            pts.append((_number(f"{where}[{i}] time", p[0]), _number(f"{where}[{i}] value", p[1])))
        for i in range(1, len(pts)):
            if pts[i][0] <= pts[i - 1][0]:
                raise SceneError(f"{where}[{i}] time {pts[i][0]:g} s must be later than {pts[i - 1][0]:g} s (times must increase)")
        self.points = tuple(pts)

    def __call__(self, t: float) -> float:
        pts = self.points
        if t <= pts[0][0]:
            return pts[0][1]
        for (t0, h0), (t1, h1) in zip(pts, pts[1:]):
            if t <= t1:
                return h0 + (h1 - h0) * (t - t0) / (t1 - t0)
        return pts[-1][1]

    @property
    def times(self) -> list[float]:
        return [t for t, _ in self.points]

    @property
    def values(self) -> list[float]:
        return [v for _, v in self.points]


FLUID_RULES = ("consistent", "paper", "quadrature")


@dataclass(slots=True)
class Fluid:
    """CSF (or oil) with a free surface at a height along up = -gravity/|gravity|.

    Give the surface either as ``level`` (m, a number or [[t, h], ...]) or, for a container,
    as ``volume`` (m3, a number or [[t, V], ...]) with the container's ``container_area``
    (m2, its footprint) and ``floor`` (the floor's height along up, m): the level then follows
    from volume = area (level - floor) - submerged volume of the body, recomputed as the body
    deforms. ``rule``: "consistent" (exact integral of p N_i over the wet part), "paper"
    (the paper's depth-weighted nodal shares, P1), "quadrature" (plain UFL quadrature of
    degree ``quadrature_degree``, a reference). ``follower``: evaluate the load on the current
    geometry x + u (the paper does), iterated to convergence within each time step and each
    quasi-static solve (one step late would be unstable: README, Follower geometry)."""

    density: float = 1000.0
    level: Schedule | Any = None
    volume: Schedule | Any = None
    container_area: float | None = None
    floor: float = 0.0
    rule: str = "consistent"
    follower: bool = True
    quadrature_degree: int = 4
    reuse_tol: float = 1e-8

    def __post_init__(self):
        self.density = _positive("[fluid] density", self.density)
        if (self.level is None) == (self.volume is None):
            raise SceneError("[fluid] give exactly one of level (m) or volume (m3, with container_area)")
        if self.level is not None and not isinstance(self.level, Schedule):
            self.level = Schedule(self.level, "[fluid] level")
        if self.volume is not None:
            if not isinstance(self.volume, Schedule):
                self.volume = Schedule(self.volume, "[fluid] volume")
            for i, (_, v) in enumerate(self.volume.points):
                if v < 0:
                    raise SceneError(f"[fluid] volume[{i}] must be >= 0 m3 (got {v:g})")
            if self.container_area is None:
                raise SceneError("[fluid] volume needs container_area (m2), the container's footprint")
            self.container_area = _positive("[fluid] container_area", self.container_area)
        self.floor = _number("[fluid] floor", self.floor)
        _choice("[fluid] rule", self.rule, FLUID_RULES)
        if not isinstance(self.follower, bool):
            raise SceneError(f"[fluid] follower must be true or false (got {self.follower!r})")
        if self.rule == "quadrature" and self.follower:
            self.follower = False  # the UFL reference integrates on the reference geometry
        self.quadrature_degree = _integer("[fluid] quadrature_degree", self.quadrature_degree, 1)
        self.reuse_tol = _non_negative("[fluid] reuse_tol", self.reuse_tol)

    @property
    def schedule(self) -> Schedule:
        return self.level if self.level is not None else self.volume


@dataclass(slots=True)
class FixedRegion:
    """Nodes where ``where`` holds are fixed along ``axes`` ("xyz" clamps; "z" slides in x-y)."""

    where: str = ""
    axes: str = "xyz"
    predicate: Predicate | None = field(default=None, repr=False)

    def __post_init__(self):
        try:
            self.predicate = parse_predicate(self.where)
        except PredicateError as exc:
            raise SceneError(f"[[fixed]] where: {exc}") from None
        if not isinstance(self.axes, str) or not self.axes or set(self.axes) - set("xyz") or len(set(self.axes)) != len(self.axes):
            raise SceneError(f"[[fixed]] axes must be letters from 'xyz' such as \"xyz\" or \"z\" (got {self.axes!r})")

    @property
    def components(self) -> list[int]:
        return sorted("xyz".index(a) for a in self.axes)


@dataclass
class Removal:
    """Resection: at time ``at`` (s) the cells whose centroid satisfies ``where``, or whose
    centroid lies in image voxels of ``label`` in the scene's label volume, are removed."""

    at: float = 0.0
    where: str | None = None
    label: int | None = None
    predicate: Predicate | None = field(default=None, repr=False)

    def __post_init__(self):
        self.at = _non_negative("[[remove]] at", self.at)
        if (self.where is None) == (self.label is None):
            raise SceneError("[[remove]] give exactly one of where = \"(x-a)**2 + ... < r**2\" or label = N")
        if self.where is not None:
            if not isinstance(self.where, str):
                raise SceneError(f"[[remove]] where must be a condition on x, y, z in quotes (got {self.where!r})")
            try:
                self.predicate = parse_predicate(self.where)
            except PredicateError as exc:
                raise SceneError(f"[[remove]] where: {exc}") from None
        else:
            self.label = _integer("[[remove]] label", self.label, 1)

    def describe(self) -> str:
        return f"where = \"{self.where}\"" if self.where is not None else f"label = {self.label}"


SCHEMES = ("newmark", "generalized-alpha")
MODES = ("auto", "dynamic", "quasi-static")


@dataclass(slots=True)
class TimeScheme:
    """dynamic: Newmark average acceleration (the paper) or generalized-alpha (rho_inf).
    quasi-static: K u = F solved at each breakpoint of the fluid level schedule.
    auto: the planner picks one of the two (planner.py)."""

    mode: str = "auto"
    scheme: str = "newmark"
    rho_inf: float = 1.0
    dt: float = 0.05
    end: float = 1.0

    def __post_init__(self):
        _choice("[time] mode", self.mode, MODES)
        _choice("[time] scheme", self.scheme, SCHEMES)
        self.rho_inf = _number("[time] rho_inf", self.rho_inf)
        if not 0.0 <= self.rho_inf <= 1.0:
            raise SceneError(f"[time] rho_inf must be in [0, 1] (got {self.rho_inf:g})")
        self.dt = _positive("[time] dt", self.dt)
        self.end = _positive("[time] end", self.end)
        if self.mode != "quasi-static" and self.end < self.dt:
            raise SceneError(f"[time] end ({self.end:g} s) must be at least one step dt ({self.dt:g} s)")

    @property
    def steps(self) -> int:
        return max(1, int(round(self.end / self.dt)))


@dataclass(slots=True)
class Damping:
    """Rayleigh damping C = a M + b K (a in 1/s, b in s)."""

    a: float = 0.0
    b: float = 0.0

    def __post_init__(self):
        self.a = _non_negative("[damping] a", self.a)
        self.b = _non_negative("[damping] b", self.b)


SOLVER_KINDS = ("cg-gamg", "cg-hypre", "cg-jacobi", "cholesky", "lu")


@dataclass(slots=True)
class SolverConfig:
    """cg-gamg: CG + PETSc's aggregation AMG with the rigid-body near-nullspace (default);
    cg-hypre: CG + hypre's BoomerAMG (iterations nearly independent of the mesh at nu -> 0.5);
    cg-jacobi: CG + diagonal (the paper's plain CG, as a baseline); cholesky/lu: direct
    (CHOLMOD on one rank, MUMPS otherwise), factor kept. ``options`` pass to PETSc under the
    prefix ``brainshift_``."""

    kind: str = "cg-gamg"
    rtol: float = 1e-10
    atol: float = 1e-30
    max_it: int = 5000
    options: dict = field(default_factory=dict)

    def __post_init__(self):
        _choice("[solver] kind", self.kind, SOLVER_KINDS)
        self.rtol = _positive("[solver] rtol", self.rtol)
        self.atol = _positive("[solver] atol", self.atol)
        self.max_it = _integer("[solver] max_it", self.max_it, 1)
        if not isinstance(self.options, dict):
            raise SceneError("[solver] options must be a table such as { ksp_monitor = true }")
        for key, value in self.options.items():
            if not isinstance(value, (str, int, float, bool)):
                raise SceneError(f"[solver] options.{key} must be a string, number or boolean")


@dataclass(slots=True)
class Element:
    """Lagrange degree 1 or 2. mass: "lumped" (P1 only: volume/4 per vertex, the paper) or
    "consistent" (the P2 default: row-sum lumping of P2 gives zero or negative corner masses)."""

    degree: int = 1
    mass: str | None = None

    def __post_init__(self):
        if self.degree not in (1, 2) or isinstance(self.degree, bool):
            raise SceneError(f"[element] degree must be 1 or 2 (got {self.degree!r})")
        if self.mass is None:
            self.mass = "lumped" if self.degree == 1 else "consistent"
        _choice("[element] mass", self.mass, ("lumped", "consistent"))
        if self.mass == "lumped" and self.degree == 2:
            raise SceneError("[element] mass = \"lumped\" is only for degree 1; use \"consistent\" with degree 2")


OUTPUT_FIELDS = ("displacement", "velocity", "von_mises")


@dataclass(slots=True)
class Output:
    """folder (``--out`` overrides), XDMF fields, interval in simulated seconds (0: every step),
    and pictures (deformed.png, probes.png) at the end."""

    folder: str = "out"
    fields: tuple[str, ...] = ("displacement",)
    interval: float = 0.0
    pictures: bool = False

    def __post_init__(self):
        if not isinstance(self.folder, str) or not self.folder:
            raise SceneError("[output] folder must be a folder name such as \"out_cube\"")
        if not isinstance(self.fields, (list, tuple)):
            raise SceneError(f"[output] fields must be a list from {', '.join(OUTPUT_FIELDS)}")
        for f in self.fields:
            _choice("[output] fields", f, OUTPUT_FIELDS)
        self.fields = tuple(self.fields)
        self.interval = _non_negative("[output] interval", self.interval)
        if not isinstance(self.pictures, bool):
            raise SceneError(f"[output] pictures must be true or false (got {self.pictures!r})")


@dataclass(slots=True)
class Scene:
    mesh: MeshSpec
    material: Material
    gravity: Gravity = field(default_factory=Gravity)
    fluid: Fluid | None = None
    fixed: tuple[FixedRegion, ...] = ()
    remove: tuple[Removal, ...] = ()
    time: TimeScheme = field(default_factory=TimeScheme)
    damping: Damping = field(default_factory=Damping)
    solver: SolverConfig = field(default_factory=SolverConfig)
    element: Element = field(default_factory=Element)
    probes: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    surfaces: dict[str, Predicate] = field(default_factory=dict)
    output: Output = field(default_factory=Output)
    name: str = "scene"

    def __post_init__(self):
        if self.fluid is not None and self.gravity.magnitude == 0.0:
            raise SceneError("[gravity] vector must be non-zero when a [fluid] is present (it defines 'up')")
        if self.fluid is not None and self.fluid.rule == "paper" and self.element.degree != 1:
            raise SceneError("[fluid] rule = \"paper\" shares forces among triangle vertices: degree 1 only; use \"consistent\"")
        if self.time.mode == "quasi-static" and not self.fixed:
            raise SceneError("[[fixed]] a quasi-static scene needs at least one fixed region (K alone is singular)")
        for r in self.remove:
            if self.time.mode == "quasi-static":
                raise SceneError("[[remove]] needs [time] mode = \"dynamic\" (or \"auto\"): a freed piece makes K "
                                 "singular, the mass matrix keeps the dynamic system solvable")
            if r.at >= self.time.end:
                raise SceneError(f"[[remove]] at = {r.at:g} s is not before [time] end = {self.time.end:g} s")
            if r.label is not None and not str(self.mesh.file or "").lower().endswith((".nii", ".nii.gz")):
                raise SceneError("[[remove]] label needs [mesh] file to be a label volume (.nii, .nii.gz); "
                                 "use where = \"...\" otherwise")
        self.remove = tuple(sorted(self.remove, key=lambda r: r.at))
        self.probes = {str(k): _vector3(f"[probes] {k}", v) for k, v in self.probes.items()}
        surfaces = {}
        for k, v in self.surfaces.items():
            try:
                surfaces[str(k)] = v if isinstance(v, Predicate) else parse_predicate(v)
            except PredicateError as exc:
                raise SceneError(f"[surfaces] {k}: {exc}") from None
        self.surfaces = surfaces


# ---------------------------------------------------------------- TOML loading
_SECTIONS = {
    "mesh": MeshSpec, "material": Material, "gravity": Gravity, "fluid": Fluid,
    "time": TimeScheme, "damping": Damping, "solver": SolverConfig, "element": Element,
    "output": Output,
}


def _build(cls, table: Any, where: str):
    if not isinstance(table, dict):
        raise SceneError(f"{where} must be a table")
    known = [f.name for f in fields(cls) if f.name != "predicate"]
    for key in table:
        if key not in known:
            raise SceneError(f"{where} unknown key '{key}'; known keys: {', '.join(known)}")
    try:
        return cls(**table)
    except TypeError as exc:  # a value of the wrong kind deep inside
        raise SceneError(f"{where} {exc}") from None


def scene_from_dict(data: dict, base: Path | None = None) -> Scene:
    """Build a Scene from parsed TOML; relative mesh files resolve against ``base``."""
    known = list(_SECTIONS) + ["fixed", "remove", "probes", "surfaces", "name"]
    for key in data:
        if key not in known:
            raise SceneError(f"unknown section [{key}]; known sections: {', '.join(known)}")
    for required in ("mesh", "material"):
        if required not in data:
            raise SceneError(f"missing section [{required}]")
    kwargs: dict[str, Any] = {name: _build(cls, data[name], f"[{name}]")
                              for name, cls in _SECTIONS.items() if name in data}
    fixed = data.get("fixed", [])
    if not isinstance(fixed, list):
        raise SceneError("[[fixed]] must be an array of tables: [[fixed]] where = \"z < 0.001\"")
    kwargs["fixed"] = tuple(_build(FixedRegion, f, "[[fixed]]") for f in fixed)
    remove = data.get("remove", [])
    if not isinstance(remove, list):
        raise SceneError("[[remove]] must be an array of tables: [[remove]] at = 10.0, where = \"...\"")
    kwargs["remove"] = tuple(_build(Removal, r, "[[remove]]") for r in remove)
    probes = data.get("probes", {})
    if not isinstance(probes, dict):
        raise SceneError("[probes] must be a table of name = [x, y, z]")
    kwargs["probes"] = probes
    surfaces = data.get("surfaces", {})
    if not isinstance(surfaces, dict):
        raise SceneError("[surfaces] must be a table of name = \"condition on x, y, z\"")
    kwargs["surfaces"] = surfaces
    if "name" in data:
        if not isinstance(data["name"], str):
            raise SceneError("name must be a string")
        kwargs["name"] = data["name"]
    mesh = kwargs["mesh"]
    if base is not None:
        if mesh.file is not None and not Path(mesh.file).is_absolute():
            mesh.file = str((base / mesh.file).resolve())
        if mesh.surface is not None and not Path(mesh.surface).is_absolute():
            mesh.surface = str((base / mesh.surface).resolve())
    return Scene(**kwargs)


def apply_override(data: dict, assignment: str) -> None:
    """Apply ``section.key=value`` (``fixed.0.where=...`` indexes arrays) to parsed TOML.

    The value is read as a TOML value (numbers, booleans, strings, arrays); a bare word that
    is not valid TOML is taken as a string, so ``solver.kind=cholesky`` works unquoted."""
    key, sep, text = assignment.partition("=")
    if not sep or not key.strip():
        raise SceneError(f"--set '{assignment}': expected section.key=value, e.g. time.end=2.0")
    try:
        value = tomllib.loads(f"v = {text.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = text.strip()
    node: Any = data
    parts = key.strip().split(".")
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise SceneError(f"--set '{key}': '{part}' is not an index of that array (0..{len(node) - 1})")
            if last:
                node[int(part)] = value
            else:
                node = node[int(part)]
        elif isinstance(node, dict):
            if last:
                node[part] = value
            else:
                node = node.setdefault(part, {})
        else:
            raise SceneError(f"--set '{key}': '{'.'.join(parts[:i])}' is a value, not a table")


def load_scene(path: str | Path, overrides: list[str] = ()) -> Scene:
    """Read and validate a scene file; every problem is a one-line SceneError.
    ``overrides`` are ``section.key=value`` strings applied before validation."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"scene file '{path}' not found")
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SceneError(f"{path.name}: not valid TOML ({exc})") from None
    for assignment in overrides:
        apply_override(data, assignment)
    scene = scene_from_dict(data, base=path.parent)
    from .meshing.voxelize import is_voxelizable

    for key in ("file", "surface"):
        name = getattr(scene.mesh, key)
        if name is None:
            continue
        if not Path(name).is_file():
            raise SceneError(f"[mesh] {key} '{name}' not found; give a path relative to the scene file")
        if not (name.endswith((".msh", ".xdmf")) or is_voxelizable(name)):
            raise SceneError(f"[mesh] {key} '{Path(name).name}': use .msh, .xdmf, a label volume (.nii, .nii.gz) "
                             f"or a surface (.stl, .obj, .ply, .vtk, .vtp, .gii)")
    return scene
