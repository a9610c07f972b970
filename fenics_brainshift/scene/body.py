"""The body: its mesh, material, element, supports and removals."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .. import formats
from ..errors import InputError
from ..units import LENGTH_UNITS
from .checks import choice, integer, non_negative, number, positive, vector3
from .predicates import Predicate, PredicateError, parse_predicate
from .schedule import Schedule

NU_MAX = 0.4999  # nearer 1/2 the displacement formulation locks (P1) or stalls (Newton)
SHAPES = ("box", "ellipsoid")


@dataclass(slots=True)
class MeshSpec:
    """A gmsh built-in shape or a mesh file.

    box: ``size`` = extents, ``origin`` = lowest corner; ``cells`` = [nx, ny, nz] gives a
    structured grid of hexahedra split into five tetrahedra each (the paper's cube grids),
    ``h`` gives an unstructured gmsh mesh of that element size.
    ellipsoid: ``size`` = semi-axes, ``origin`` = centre, ``h`` = element size.
    file: .msh (gmsh) or .xdmf (DOLFINx/meshio) tetrahedral mesh, or a segmentation to be
    voxel-meshed (the paper's embedding method): a label volume (.nii, .nii.gz, .nrrd, .seg.nrrd) or a surface
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
    labels: tuple[int | str, ...] | None = None  # values, or a .seg.nrrd's segment names
    surface: str | None = None

    def __post_init__(self):
        if (self.shape is None) == (self.file is None):
            raise InputError('[mesh] give exactly one of shape = "box" or file = "mesh.msh"')
        if self.shape is not None:
            choice("[mesh] shape", self.shape, SHAPES)
        self.size = vector3("[mesh] size", self.size)
        for i, s in enumerate(self.size):
            positive(f"[mesh] size[{i}]", s)
        self.origin = vector3("[mesh] origin", self.origin)
        if self.cells is not None:
            if not isinstance(self.cells, (list, tuple)) or len(self.cells) != 3:
                raise InputError(f"[mesh] cells must be [nx, ny, nz] (got {self.cells!r})")
            self.cells = tuple(integer(f"[mesh] cells[{i}]", c, 1) for i, c in enumerate(self.cells))
        if self.h is not None:
            self.h = positive("[mesh] h", self.h)
        if self.shape == "box" and (self.cells is None) == (self.h is None):
            raise InputError("[mesh] a box needs either cells = [nx, ny, nz] or h = element size")
        if self.shape == "ellipsoid" and self.h is None:
            raise InputError("[mesh] an ellipsoid needs h = element size (m)")
        choice("[mesh] unit", self.unit, tuple(LENGTH_UNITS))
        if self.voxel is not None:
            self.voxel = positive("[mesh] voxel", self.voxel)
        self.fill = number("[mesh] fill", self.fill)
        if not 0.0 <= self.fill <= 1.0:
            raise InputError(
                f"[mesh] fill must be in [0, 1] (got {self.fill:g}); 0 keeps every voxel the object touches"
            )
        self.parts = integer("[mesh] parts", self.parts, 1)
        if self.labels is not None:
            if not isinstance(self.labels, (list, tuple)) or not all(
                isinstance(v, (int, str)) and not isinstance(v, bool) for v in self.labels
            ):
                raise InputError(f"[mesh] labels must be a list of label values or segment names (got {self.labels!r})")
            self.labels = tuple(self.labels)
        if self.file is not None and self.needs_voxels and self.voxel is None:
            raise InputError(
                f"[mesh] file '{Path(self.file).name}' is a segmentation: give voxel = size in m (e.g. 0.005)"
            )
        if self.surface is not None and not isinstance(self.surface, str):
            raise InputError("[mesh] surface must be a file name")

    @property
    def scale(self) -> float:
        return LENGTH_UNITS[self.unit]

    @property
    def needs_voxels(self) -> bool:
        return not formats.is_tetra_mesh(self.file)


MATERIAL_MODELS = ("linear", "neo-hookean", "saint-venant-kirchhoff", "auto")


@dataclass(slots=True)
class Material:
    """E and nu, or G (shear modulus) and nu; density in kg/m3. ``model``: "linear" (small
    strain), "neo-hookean" or "saint-venant-kirchhoff" (finite deformation, the same small-
    strain limit). ``E_sd`` or ``G_sd``: the modulus's standard deviation, for the stiffness
    band in summary.json."""

    nu: float = 0.45
    density: float = 1000.0
    E: float | None = None
    G: float | None = None
    E_sd: float | None = None
    G_sd: float | None = None
    model: str = "linear"

    def __post_init__(self):
        if (self.E is None) == (self.G is None):
            raise InputError("[material] give exactly one of E (Young's modulus, Pa) or G (shear modulus, Pa)")
        choice("[material] model", self.model, MATERIAL_MODELS)
        self.nu = number("[material] nu", self.nu)
        if not -1.0 < self.nu <= NU_MAX:
            raise InputError(
                f"[material] nu must be in (-1, {NU_MAX:g}] (got {self.nu:.10g}); 0.5 is incompressible, which "
                f"this displacement formulation cannot hold (P1 locks, Newton stalls)"
            )
        self.density = positive("[material] density", self.density)
        if self.G is not None:
            self.G = positive("[material] G", self.G)
            self.E = 2.0 * self.G * (1.0 + self.nu)
        else:
            self.E = positive("[material] E", self.E)
            self.G = self.E / (2.0 * (1.0 + self.nu))
        if self.E_sd is not None and self.G_sd is not None:
            raise InputError("[material] give at most one of E_sd or G_sd")
        for key, modulus in (("E_sd", self.E), ("G_sd", self.G)):
            sd = getattr(self, key)
            if sd is not None:
                sd = positive(f"[material] {key}", sd)
                if sd >= modulus:
                    raise InputError(
                        f"[material] {key} = {sd:g} must be below the modulus ({modulus:g}): "
                        f"the band's soft end would have no stiffness"
                    )
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
class FixedRegion:
    """Nodes where ``where`` holds, or that lie in image voxels of ``label`` (a value or a
    segment name of the scene's label volume: an anatomical support such as the brain stem),
    are fixed along ``axes`` ("xyz" clamps; "z" slides in x-y)."""

    where: str | None = None
    axes: str = "xyz"
    label: int | str | None = None
    name: str | None = None  # for messages, and what `brainshift prepare` calls the anatomy
    predicate: Predicate | None = field(default=None, repr=False)

    def __post_init__(self):
        if self.name is not None and (not isinstance(self.name, str) or not self.name.isidentifier()):
            raise InputError(
                f'[[fixed]] name must be a word of letters, digits and _ such as "brain_stem" (got {self.name!r})'
            )
        if (self.where is None) == (self.label is None):
            raise InputError(
                '[[fixed]] give exactly one of where = "z < 0.01" or label = N (a label or segment '
                "name of [mesh] file's label volume)"
            )
        if self.where is not None:
            try:
                self.predicate = parse_predicate(self.where)
            except PredicateError as exc:
                raise InputError(f"[[fixed]] where: {exc}") from None
        elif not isinstance(self.label, str):
            self.label = integer("[[fixed]] label", self.label, 1)
        if (
            not isinstance(self.axes, str)
            or not self.axes
            or set(self.axes) - set("xyz")
            or len(set(self.axes)) != len(self.axes)
        ):
            raise InputError(f'[[fixed]] axes must be letters from \'xyz\' such as "xyz" or "z" (got {self.axes!r})')

    @property
    def components(self) -> list[int]:
        return sorted("xyz".index(a) for a in self.axes)

    def describe(self) -> str:
        return f'where = "{self.where}"' if self.where is not None else f"label = {self.label!r}"


@dataclass
class Removal:
    """Resection: at time ``at`` (s) the cells whose centroid satisfies ``where``, or whose
    centroid lies in image voxels of ``label`` in the scene's label volume, are removed."""

    at: float = 0.0
    where: str | None = None
    label: int | str | None = None  # a value, or a .seg.nrrd's segment name
    predicate: Predicate | None = field(default=None, repr=False)

    def __post_init__(self):
        self.at = non_negative("[[remove]] at", self.at)
        if (self.where is None) == (self.label is None):
            raise InputError('[[remove]] give exactly one of where = "(x-a)**2 + ... < r**2" or label = N')
        if self.where is not None:
            if not isinstance(self.where, str):
                raise InputError(f"[[remove]] where must be a condition on x, y, z in quotes (got {self.where!r})")
            try:
                self.predicate = parse_predicate(self.where)
            except PredicateError as exc:
                raise InputError(f"[[remove]] where: {exc}") from None
        elif not isinstance(self.label, str):
            self.label = integer("[[remove]] label", self.label, 1)

    def describe(self) -> str:
        return f'where = "{self.where}"' if self.where is not None else f"label = {self.label}"


@dataclass
class Swelling:
    """Shrinkage or swelling of the tissue: the cells whose centroid satisfies ``where``, or
    lies in image voxels of ``label``, change their free (stress-free) volume by
    ``volume_change`` (-0.03 shrinks them by 3 %, 0.05 swells them by 5 %), times ``schedule``:
    a fraction, a number or [[t, fraction], ...] piecewise linear (a drug acting over minutes;
    default 1, from the start)."""

    volume_change: float = 0.0
    where: str | None = None
    label: int | str | None = None
    schedule: object = 1.0
    predicate: Predicate | None = field(default=None, repr=False)

    def __post_init__(self):
        self.volume_change = number("[[swelling]] volume_change", self.volume_change)
        if not -1.0 < self.volume_change < 1.0 or self.volume_change == 0.0:
            raise InputError(
                f"[[swelling]] volume_change is a fraction of the volume, not zero and between -1 and 1 "
                f"(got {self.volume_change:g}): -0.03 shrinks by 3 %, 0.05 swells by 5 %"
            )
        if (self.where is None) == (self.label is None):
            raise InputError('[[swelling]] give exactly one of where = "(x-a)**2 + ... < r**2" or label = N')
        if self.where is not None:
            if not isinstance(self.where, str):
                raise InputError(f"[[swelling]] where must be a condition on x, y, z in quotes (got {self.where!r})")
            try:
                self.predicate = parse_predicate(self.where)
            except PredicateError as exc:
                raise InputError(f"[[swelling]] where: {exc}") from None
        elif not isinstance(self.label, str):
            self.label = integer("[[swelling]] label", self.label, 1)
        if not isinstance(self.schedule, Schedule):
            self.schedule = Schedule(self.schedule, "[[swelling]] schedule")
        for t, fraction in self.schedule.points:
            if t < 0.0 or not 0.0 <= fraction <= 1.0:
                raise InputError(
                    f"[[swelling]] schedule: a fraction of volume_change in [0, 1] at a time >= 0 s "
                    f"(got [{t:g}, {fraction:g}]); give the size of the change in volume_change"
                )

    def describe(self) -> str:
        where = f'where = "{self.where}"' if self.where is not None else f"label = {self.label}"
        return f"{where}, volume_change = {self.volume_change:+g}"

    def at(self, t: float) -> float:
        """The region's free volume change at time t."""
        return self.volume_change * self.schedule(t)
