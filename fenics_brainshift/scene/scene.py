"""A scene: every section together, with the checks that need more than one section."""

from __future__ import annotations

from dataclasses import dataclass, field

from .. import formats
from ..errors import InputError
from .body import FixedRegion, Material, MeshSpec, Removal, Swelling
from .checks import vector3
from .loads import Fluid, Gravity
from .numerics import Damping, Element, Output, SolverConfig, TimeScheme
from .predicates import Predicate, PredicateError, parse_predicate
from .septum import SeptumSpec
from .skull import Skull

MAX_RHO_INF_WITH_CONTACT = 0.5  # a block bouncing on the floor kept its energy bounded at 0.5, not at 0.8


@dataclass(slots=True)
class Scene:
    """Every input of a run, validated: the mesh, material, gravity, fluid, skull, supports,
    removals, swelling, septa, time, damping, solver, element, probes and output (docs/scenes.md)."""

    mesh: MeshSpec
    material: Material
    gravity: Gravity = field(default_factory=Gravity)
    fluid: Fluid | None = None
    skull: Skull | None = None
    fixed: tuple[FixedRegion, ...] = ()
    remove: tuple[Removal, ...] = ()
    swelling: tuple[Swelling, ...] = ()
    septa: tuple[SeptumSpec, ...] = ()  # the enabled [[septum]] entries
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
            raise InputError("[gravity] vector must be non-zero when a [fluid] is present (it defines 'up')")
        if self.fluid is not None and self.fluid.rule == "paper" and self.element.degree != 1:
            raise InputError(
                '[fluid] rule = "paper" shares forces among triangle vertices: degree 1 only; use "consistent"'
            )
        glued = self.skull is not None and self.skull.glue is not None
        if self.time.mode == "quasi-static" and not self.fixed and not glued and not self.septa:
            raise InputError(
                "[[fixed]] a quasi-static scene needs at least one fixed region (K alone is singular; "
                "with a [skull], its fixed_where also holds; septa that hold every rigid motion do)"
            )
        for f in self.fixed:
            if f.label is not None and not formats.is_label_volume(self.mesh.file or ""):
                raise InputError(
                    "[[fixed]] label needs [mesh] file to be a label volume (.nii, .nii.gz, .nrrd); "
                    'use where = "..." otherwise'
                )
        for s in self.septa:
            if s.label is not None and not formats.is_label_volume(self.mesh.file or ""):
                raise InputError(
                    f"[[septum]] {s.title} label needs [mesh] file to be a label volume (.nii, .nii.gz, "
                    f".nrrd); give a plane (point, normal) or a file otherwise"
                )
        for r in self.remove:
            if r.at >= self.time.end:
                raise InputError(f"[[remove]] at = {r.at:g} s is not before [time] end = {self.time.end:g} s")
            if self.fluid is not None and self.fluid.rule == "quadrature":
                raise InputError(
                    "[[remove]] needs the fluid load on the surface left after the cut: use [fluid] "
                    'rule = "consistent" ("quadrature" acts on the original surface only)'
                )
            if r.label is not None and not formats.is_label_volume(self.mesh.file or ""):
                raise InputError(
                    "[[remove]] label needs [mesh] file to be a label volume (.nii, .nii.gz, .nrrd); "
                    'use where = "..." otherwise'
                )
        for r in self.swelling:
            if r.label is not None and not formats.is_label_volume(self.mesh.file or ""):
                raise InputError(
                    "[[swelling]] label needs [mesh] file to be a label volume (.nii, .nii.gz, .nrrd); "
                    'use where = "..." otherwise'
                )
        if (
            self.skull is not None
            and self.skull.label is not None
            and not formats.is_label_volume(self.mesh.file or "")
        ):
            raise InputError(
                "[skull] label needs [mesh] file to be a label volume (.nii, .nii.gz, .nrrd); give "
                'file = "skull.stl" or gap = 0.003 otherwise'
            )
        if (
            self.skull is not None
            and self.time.mode != "quasi-static"
            and (self.time.scheme != "generalized-alpha" or self.time.rho_inf > MAX_RHO_INF_WITH_CONTACT)
        ):
            # Newmark enforcing contact at the step's end pumps energy in at every impact
            # (measured: a block bouncing on the floor gains energy even with damping)
            raise InputError(
                f'[skull] time stepping with contact needs [time] scheme = "generalized-alpha" with '
                f"rho_inf <= {MAX_RHO_INF_WITH_CONTACT:g} (its damping of the highest modes keeps "
                f'impacts from adding energy); or use mode = "quasi-static"'
            )
        self.remove = tuple(sorted(self.remove, key=lambda r: r.at))
        probes = {}
        for k, v in self.probes.items():
            probes[_column_name(str(k), probes)] = vector3(f"[probes] {k}", v)
        self.probes = probes
        surfaces = {}
        for k, v in self.surfaces.items():
            try:
                surfaces[_column_name(str(k), surfaces)] = v if isinstance(v, Predicate) else parse_predicate(v)
            except PredicateError as exc:
                raise InputError(f"[surfaces] {k}: {exc}") from None
        self.surfaces = surfaces

    @property
    def settled_time(self) -> float:
        """The time whose loads a settled (drained) state of the scene takes, as the atlas and the
        fit solve it: the end of its level and swelling schedules, or [time] end if later. A
        quasi-static run solves every breakpoint whatever [time] end says, so a scene that drains
        over 10 s with the default end of 1 s still ends drained (a prepared patient's)."""
        times = [self.time.end]
        if self.fluid is not None and self.fluid.volume is None and self.fluid.level:
            times += list(self.fluid.level.times)
        for r in self.swelling:
            times += list(r.schedule.times)
        return float(max(times))


def _column_name(name: str, taken: dict) -> str:
    """A probe's or surface's name as probes.csv's columns can hold it: commas, quotes and line
    breaks (a Slicer label "A,1" or with a newline would split the header) become "_", and a
    name taken already gets a prime."""
    safe = "".join("_" if c in ',"\r\n' else c for c in name).strip() or "_"
    while safe in taken:
        safe += "'"
    return safe
