"""[skull]: the rigid inner skull the brain slides along (frictionless) but cannot pass.

A closed triangulated surface from a file (the mesh's unit); or the boundary of labels of the
scene's label volume (``label``: those of everything inside the skull, brain and CSF; meshed
by marching cubes); or, where no skull is segmented, the brain's own surface dilated by
``gap`` (the CSF layer). ``fixed_where`` glues
the nodes there to the skull (a brain-stem or tentorium region). ``tolerance`` is the
penetration the contact solution may keep (m): the augmented Lagrangian iterates until the
deepest node is within it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .. import formats
from ..errors import InputError
from .checks import positive
from .predicates import Predicate, PredicateError, parse_predicate


@dataclass
class Skull:
    file: str | None = None
    gap: float | None = None
    label: int | str | list | None = None  # label values or segment names of the inside of the skull
    fixed_where: str | None = None
    tolerance: float = 1e-5
    glue: Predicate | None = field(default=None, repr=False)

    def __post_init__(self):
        if sum(v is not None for v in (self.file, self.gap, self.label)) != 1:
            raise InputError(
                "[skull] give exactly one of file (a closed surface: .stl, .ply, .vtk, ...), label (the "
                "labels inside the skull in [mesh] file's label volume, e.g. [1, 2]) or gap (m, the CSF "
                "layer between the brain's surface and the skull, e.g. 0.003)"
            )
        if self.label is not None:
            labels = self.label if isinstance(self.label, list) else [self.label]
            if not labels or not all(isinstance(v, (int, str)) and not isinstance(v, bool) for v in labels):
                raise InputError(
                    f"[skull] label must be a label value, a segment name or a list of them, such as "
                    f"[1, 2] (got {self.label!r})"
                )
            self.label = labels
        if self.gap is not None:
            if isinstance(self.gap, bool) or not isinstance(self.gap, (int, float)) or not 0 < self.gap < float("inf"):
                raise InputError(f"[skull] gap must be a positive distance in m, such as 0.003 (got {self.gap!r})")
            self.gap = float(self.gap)
        if self.file is not None:
            if not isinstance(self.file, str) or not formats.is_surface(self.file):
                raise InputError(
                    f"[skull] file must be a closed triangulated surface "
                    f"({', '.join(formats.SURFACE_SUFFIXES)}); got {self.file!r}"
                )
        self.tolerance = positive("[skull] tolerance", self.tolerance)
        if self.fixed_where is not None:
            try:
                self.glue = parse_predicate(self.fixed_where)
            except PredicateError as exc:
                raise InputError(f"[skull] fixed_where: {exc}") from None
