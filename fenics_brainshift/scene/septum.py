"""[[septum]]: a rigid membrane fixed to the skull (the falx, the tentorium) that the tissue
slides along and does not cross."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import InputError
from .checks import integer, positive, vector3
from .predicates import Predicate, PredicateError, parse_predicate


@dataclass
class SeptumSpec:
    """A plane through ``point`` with ``normal`` (mesh frame, metres after [mesh] unit), or a
    surface ``file`` (in the mesh's unit), or the boundary of ``label`` of the label volume;
    ``where`` limits it to a region (a condition on the nodes' x, y, z); ``reach`` (m): on a
    mesh with a fissure, every node within it of the septum touches it (default: the layer of
    nodes nearest to it); ``name`` for messages, the summary and --set septum.NAME.KEY;
    ``enabled = false`` leaves it out. Unnamed, it is "septumN" (its place in the file)."""

    name: str | None = None
    point: tuple[float, float, float] | None = None
    normal: tuple[float, float, float] | None = None
    file: str | None = None
    label: int | str | None = None
    where: str | None = None
    reach: float | None = None
    enabled: bool = True
    predicate: Predicate | None = field(default=None, repr=False)

    def __post_init__(self):
        given = [k for k in ("normal", "file", "label") if getattr(self, k) is not None]
        if len(given) != 1:
            raise InputError(
                f"[[septum]] {self.title}: give exactly one of normal = [nx, ny, nz] (with point), "
                f'file = "septum.stl" or label = N (got {", ".join(given) or "none"})'
            )
        if self.normal is not None:
            if self.point is None:
                raise InputError(f"[[septum]] {self.title}: a plane needs point = [x, y, z] (m) as well as normal")
            self.point = vector3(f"[[septum]] {self.title} point", self.point)
            self.normal = vector3(f"[[septum]] {self.title} normal", self.normal)
            if max(abs(v) for v in self.normal) == 0.0:
                raise InputError(f"[[septum]] {self.title} normal must not be zero")
        elif self.point is not None:
            raise InputError(
                f"[[septum]] {self.title}: point belongs to a plane (with normal); a file or label "
                f"septum has its own position"
            )
        if self.file is not None and not isinstance(self.file, str):
            raise InputError(f"[[septum]] {self.title} file must be a file name (got {self.file!r})")
        if self.label is not None and not isinstance(self.label, str):
            self.label = integer(f"[[septum]] {self.title} label", self.label, 1)
        if self.where is not None:
            if not isinstance(self.where, str):
                raise InputError(
                    f"[[septum]] {self.title} where must be a condition on x, y, z in quotes (got {self.where!r})"
                )
            try:
                self.predicate = parse_predicate(self.where)
            except PredicateError as exc:
                raise InputError(f"[[septum]] {self.title} where: {exc}") from None
        if self.reach is not None:
            self.reach = positive(f"[[septum]] {self.title} reach", self.reach)
        if not isinstance(self.enabled, bool):
            raise InputError(f"[[septum]] {self.title} enabled must be true or false (got {self.enabled!r})")
        if self.name is not None and (not isinstance(self.name, str) or not self.name.isidentifier()):
            raise InputError(
                f'[[septum]] name must be a word of letters, digits and _ such as "falx" (got {self.name!r})'
            )

    @property
    def title(self) -> str:
        return self.name if isinstance(self.name, str) else "(unnamed)"

    def describe(self) -> str:
        if self.normal is not None:
            what = f"plane through {list(self.point)} normal {list(self.normal)}"
        elif self.file is not None:
            what = f"surface {self.file.rsplit('/', 1)[-1]}"
        else:
            what = f"boundary of label {self.label}"
        return what + (f' where "{self.where}"' if self.where else "")
