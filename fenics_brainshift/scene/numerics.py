"""How a scene is solved and written: time scheme, damping, solver, element, output."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import InputError
from .checks import choice, integer, non_negative, number, positive

SCHEMES = ("newmark", "generalized-alpha")
MODES = ("auto", "dynamic", "quasi-static")


@dataclass(slots=True)
class TimeScheme:
    """dynamic: Newmark average acceleration (the paper) or generalized-alpha (rho_inf).
    quasi-static: K u = F solved at each breakpoint of the fluid level schedule.
    auto: the planner picks one of the two (runner/plan.py)."""

    mode: str = "auto"
    scheme: str = "newmark"
    rho_inf: float = 1.0
    dt: float = 0.05
    end: float = 1.0

    def __post_init__(self):
        choice("[time] mode", self.mode, MODES)
        choice("[time] scheme", self.scheme, SCHEMES)
        self.rho_inf = number("[time] rho_inf", self.rho_inf)
        if not 0.0 <= self.rho_inf <= 1.0:
            raise InputError(f"[time] rho_inf must be in [0, 1] (got {self.rho_inf:g})")
        self.dt = positive("[time] dt", self.dt)
        self.end = positive("[time] end", self.end)
        if self.mode != "quasi-static" and self.end < self.dt:
            raise InputError(f"[time] end ({self.end:g} s) must be at least one step dt ({self.dt:g} s)")

    @property
    def steps(self) -> int:
        return max(1, int(round(self.end / self.dt)))


@dataclass(slots=True)
class Damping:
    """Rayleigh damping C = a M + b K (a in 1/s, b in s)."""

    a: float = 0.0
    b: float = 0.0

    def __post_init__(self):
        self.a = non_negative("[damping] a", self.a)
        self.b = non_negative("[damping] b", self.b)


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
        choice("[solver] kind", self.kind, SOLVER_KINDS)
        self.rtol = positive("[solver] rtol", self.rtol)
        self.atol = positive("[solver] atol", self.atol)
        self.max_it = integer("[solver] max_it", self.max_it, 1)
        if not isinstance(self.options, dict):
            raise InputError("[solver] options must be a table such as { ksp_monitor = true }")
        for key, value in self.options.items():
            if not isinstance(value, (str, int, float, bool)):
                raise InputError(f"[solver] options.{key} must be a string, number or boolean")


@dataclass(slots=True)
class Element:
    """Lagrange degree 1 or 2. mass: "lumped" (P1 only: volume/4 per vertex, the paper) or
    "consistent" (the P2 default: row-sum lumping of P2 gives zero or negative corner masses)."""

    degree: int = 1
    mass: str | None = None

    def __post_init__(self):
        if self.degree not in (1, 2) or isinstance(self.degree, bool):
            raise InputError(f"[element] degree must be 1 or 2 (got {self.degree!r})")
        if self.mass is None:
            self.mass = "lumped" if self.degree == 1 else "consistent"
        choice("[element] mass", self.mass, ("lumped", "consistent"))
        if self.mass == "lumped" and self.degree == 2:
            raise InputError('[element] mass = "lumped" is only for degree 1; use "consistent" with degree 2')


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
            raise InputError('[output] folder must be a folder name such as "out_cube"')
        if not isinstance(self.fields, (list, tuple)):
            raise InputError(f"[output] fields must be a list from {', '.join(OUTPUT_FIELDS)}")
        for f in self.fields:
            choice("[output] fields", f, OUTPUT_FIELDS)
        self.fields = tuple(self.fields)
        self.interval = non_negative("[output] interval", self.interval)
        if not isinstance(self.pictures, bool):
            raise InputError(f"[output] pictures must be true or false (got {self.pictures!r})")
