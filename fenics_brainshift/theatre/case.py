"""An operation's measurements against a prepared atlas, updated as they arrive: the object a
team writing its own bridge holds (and `brainshift serve` and `brainshift update` use).

The atlas is prepared once, when the case is made (before the measurements arrive); every
update then fits the points the case holds now:
- a point list (a navigation system's, Slicer's markups), replaced whole each time it is sent:
  points whose labels are among the pre-operative points are fitted point to point, the
  others point to the surface (a tracked pointer's touches on the cortex);
- touches captured from a tracked pointer's tip (`capture`), kept until reset or undone;
- a surface scan (a laser or stereo scan's points), thinned to MAX_SCAN_POINTS.
Positions are RAS metres here; the service converts a client's frame and millimetres.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

import numpy as np

from ..atlas.prepared import locator
from ..atlas.update import UpdateResult, prepare, update
from ..errors import InputError
from ..images.targets import Target
from .grid import Grid
from .suggest import Suggestion, exposed_cortex, suggest

MAX_SCAN_POINTS = 2000  # a scan's points are thinned to this many (each is a row of the fit)
MAX_POINTS = 1000  # in a point list
OUTSIDE_BODY = 50e-3  # m: a point farther than this outside the atlas's bounding box is refused
HISTORY = 100  # states kept for undo
LABEL_BYTES = 64  # the longest point name OpenIGTLink carries
# a live case keeps the regularisation's alpha of its last cross-validation while the points
# it was chosen on are at least ALPHA_MIN_POINTS and differ in number by at most ALPHA_KEPT
# (a list growing touch by touch pays for the cross-validation once in a while:
# benchmarks/results/serve.md splits an update's time)
ALPHA_MIN_POINTS = 10
ALPHA_KEPT = 0.25


@dataclass
class Answer:
    """An update and what goes back to the surgeon, RAS metres."""

    result: UpdateResult
    target: Target
    surface: tuple[np.ndarray, np.ndarray] | None  # the moved surface: points (S, 3), triangles (T, 3)
    structures: dict  # name -> (points (P, 3), triangles): the segmented structures given, moved
    targets: tuple[list[str], np.ndarray]  # the targets of interest, moved
    pre: tuple[list[str], np.ndarray]  # the pre-operative points, moved
    displacement: np.ndarray | None  # (i, j, k, 3) on the case's grid
    spread: np.ndarray | None  # (i, j, k)
    suggestion: Suggestion | None
    status: dict = field(default_factory=dict)


@dataclass
class _State:
    labels: list[str] = field(default_factory=list)
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    touches: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    scan: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


class Case:
    """The case of one operation on a prepared atlas (atlas/store.py's Atlas).

    pre, targets: (labels, (n, 3) m) or None; targets default to the atlas's probes (the
    craniotomy, a patient's anatomy): where the uncertainty matters and the suggestions aim.
    grid: the displacement image's spacing (m; None: no image). structures: name -> (points
    (P, 3) m, triangles): surfaces of segmented structures (a tumour, the ventricles) that each
    update moves with the brain."""

    def __init__(
        self,
        atlas,
        pre: tuple[list[str], np.ndarray] | None = None,
        targets: tuple[list[str], np.ndarray] | None = None,
        noise: float = 1e-3,
        grid: float | None = 4e-3,
        samples: int = 0,
        set_aside: bool = True,
        structures: dict | None = None,
    ):
        self.atlas, self.noise, self.samples, self.set_aside = atlas, noise, samples, set_aside
        started = time.perf_counter()
        prepare(atlas)
        lo, hi = atlas.points.min(axis=0), atlas.points.max(axis=0)
        self._box = (lo - OUTSIDE_BODY, hi + OUTSIDE_BODY)
        self.pre = self._checked(*pre, "the pre-operative points") if pre else ([], np.zeros((0, 3)))
        self._pre_at = dict(zip(self.pre[0], self.pre[1]))
        probes = atlas.info.get("probes") or {}
        if targets is None:
            targets = (list(probes), np.array([probes[k] for k in probes], dtype=float).reshape(-1, 3))
        self.targets = self._checked(*targets, "the targets") if len(targets[0]) else ([], np.zeros((0, 3)))
        self._targets_at, self._pre_at_mesh = self._located(self.targets[1]), self._located(self.pre[1])
        self.grid = Grid(atlas.points, atlas.tetrahedra, grid) if grid else None
        self.structures = {name: self._structure(name, *surface) for name, surface in (structures or {}).items()}
        up = -np.asarray(atlas.info.get("gravity", [0.0, 0.0, -9.81]), dtype=float)
        centre = probes.get("craniotomy")
        if centre is None:  # (no craniotomy said: the top of the brain, against gravity)
            centre = atlas.points[np.argmax(atlas.points @ up)]
        self.candidates = exposed_cortex(atlas, np.asarray(centre, dtype=float), up / np.linalg.norm(up))
        self._state, self._history = _State(), []
        self.last: Answer | None = None
        self._alpha: tuple[float, int, str] | None = None  # (alpha, points, kind) of the last cross-validation
        self.prepare_s = time.perf_counter() - started

    def fresh(self, like: Case | None = None) -> Case:
        """A new case on the same prepared atlas, targets and grid (made once), holding no
        measurements, or those `like` holds now (a restarted service resumes a recorded case)."""
        case = copy.copy(self)
        case._state = like._state if like is not None else _State()
        case._history, case.last, case._alpha = [], None, None
        return case

    # -- what arrives ----------------------------------------------------------------------

    def set_points(self, labels: list[str], positions: np.ndarray) -> None:
        """Replace the point list (a markups list sent whole each time it changes)."""
        labels, positions = self._checked(labels, positions, "the point list")
        if len(labels) > MAX_POINTS:
            raise InputError(f"the point list: {len(labels)} points (at most {MAX_POINTS}); send a thinned list")
        self._push(labels=labels, positions=positions)

    def capture(self, position: np.ndarray) -> None:
        """Keep a tracked pointer's tip as a touch of the cortex."""
        _, tip = self._checked(["tip"], np.reshape(position, (1, 3)), "the pointer's tip")
        self._push(touches=np.vstack([self._state.touches, tip]))

    def set_scan(self, points: np.ndarray) -> None:
        """Replace the surface scan (its points, thinned evenly to MAX_SCAN_POINTS)."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        if len(points) > MAX_SCAN_POINTS:
            points = points[np.linspace(0, len(points) - 1, MAX_SCAN_POINTS).astype(int)]
        _, points = self._checked([f"scan{i + 1}" for i in range(len(points))], points, "the surface scan")
        self._push(scan=points)

    def undo(self) -> bool:
        """Back to the state before the last change; False when there is none."""
        if not self._history:
            return False
        self._state = self._history.pop()
        return True

    def reset(self) -> None:
        """Forget every measurement (undo brings them back)."""
        self._push(labels=[], positions=np.zeros((0, 3)), touches=np.zeros((0, 3)), scan=np.zeros((0, 3)))

    @property
    def counts(self) -> dict[str, int]:
        s = self._state
        pairs = sum(label in self._pre_at for label in s.labels)
        return {"pairs": pairs, "surface": len(s.labels) - pairs, "touches": len(s.touches), "scan": len(s.scan)}

    # -- the update --------------------------------------------------------------------------

    def target(self) -> Target:
        """The points held now: pairs first where labels match the pre-operative points."""
        s = self._state
        pre = np.array([self._pre_at.get(label, np.full(3, np.nan)) for label in s.labels]).reshape(-1, 3)
        labels = list(s.labels) + [f"touch{i + 1}" for i in range(len(s.touches))]
        labels += [f"scan{i + 1}" for i in range(len(s.scan))]
        measured = np.vstack([s.positions, s.touches, s.scan])
        pre = np.vstack([pre, np.full((len(s.touches) + len(s.scan), 3), np.nan)])
        return Target(measured, pre if np.isfinite(pre).any() else None, labels)

    def update(self, target: Target | None = None, alpha: float | None = None) -> Answer:
        """The update to the points held now (alpha kept from the last cross-validation while
        the points are near as many: ALPHA_KEPT), or to `target` (alpha chosen anew, or the
        one given: another resection stage's on the same points)."""
        live = target is None
        target = self.target() if live else target
        started = time.perf_counter()
        alpha = self._kept_alpha(target) if live else alpha
        result = update(self.atlas, target, self.noise, self.samples, set_aside=self.set_aside, alpha=alpha)
        if result.curve:
            self._alpha = (result.alpha, len(target.measured), target.kind)
        surface = None
        if self.atlas.surface_points is not None:
            surface = (self.atlas.surface_points + result.surface_displacement, self.atlas.surface_triangles)
        answer = Answer(
            result,
            target,
            surface,
            {
                name: (points + np.einsum("nj,njd->nd", weight, result.displacement[index]), triangles)
                for name, (points, triangles, index, weight) in self.structures.items()
            },
            (self.targets[0], self._moved(self._targets_at, result.displacement)),
            (self.pre[0], self._moved(self._pre_at_mesh, result.displacement)),
            None if self.grid is None else self.grid.sample(result.displacement),
            None if self.grid is None else self.grid.sample(result.spread),
            suggest(self.atlas, result, self.targets[1], self.candidates, self.noise),
        )
        answer.status = self._status(answer, time.perf_counter() - started)
        self.last = answer
        return answer

    def _structure(self, name: str, points: np.ndarray, triangles: np.ndarray):
        """(points, triangles, and where each point lies in the mesh: made once)."""
        index, weight, outside = locator(self.atlas).weights(points)
        far = float(outside.max(initial=0.0))
        if far > OUTSIDE_BODY:
            raise InputError(
                f"--structure {name}: a point lies {far * 1e3:.0f} mm outside the atlas's brain: another frame "
                f"(RAS/LPS), unit or patient?"
            )
        return points, triangles, index, weight

    def _kept_alpha(self, target: Target) -> float | None:
        if self._alpha is None:
            return None
        alpha, points, kind = self._alpha
        n = len(target.measured)
        if kind != target.kind or min(n, points) < ALPHA_MIN_POINTS or abs(n - points) > ALPHA_KEPT * points:
            return None
        return alpha

    def _located(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(points, the vertices and weights of their places in the mesh): made once."""
        if not len(points):
            return points, np.zeros((0, 4), dtype=np.int64), np.zeros((0, 4))
        return (points, *locator(self.atlas).weights(points)[:2])

    @staticmethod
    def _moved(located, u: np.ndarray) -> np.ndarray:
        points, index, weight = located
        return points + np.einsum("nj,njd->nd", weight, u[index])

    def _status(self, answer: Answer, seconds: float) -> dict:
        r, mm = answer.result, 1e3
        rms = lambda x: float(np.sqrt(np.mean(x**2))) * mm if len(x) else None  # noqa: E731
        keep = np.ones(len(r.residual), dtype=bool)
        keep[r.outliers] = False
        loo = r.leave_one_out[keep]
        s = answer.suggestion
        family = r.family_weights(self.atlas)[:3]
        return {
            "atlas_id": self.atlas.info.get("build_id") or self.atlas.mesh_id(),
            "kind": answer.target.kind,
            "points": len(answer.target.measured),
            **self.counts,
            "prior_residual_mm": rms(r.prior_residual[keep]),
            "residual_mm": rms(r.residual[keep]),
            "leave_one_out_mm": float(np.sqrt(np.nanmean(loo**2))) * mm if np.isfinite(loo).any() else None,
            "set_aside": [answer.target.labels[i] for i in r.outliers],
            "noise_mm": self.noise * mm,
            "alpha": r.alpha,
            "alpha_from": "cross-validation"
            if r.curve
            else f"kept (cross-validated on {self._alpha[1]} points)"
            if self._alpha is not None
            else "given (cross-validated on these points at another resection stage)",
            "stiffness_G_Pa": r.stiffness(self.atlas),
            "fluid_level_m": (
                float(
                    sum(f["weight"] * f["fluid.level"] for f in family if "fluid.level" in f)
                    / sum(f["weight"] for f in family if "fluid.level" in f)
                )
                if any("fluid.level" in f for f in family)
                else None
            ),
            "largest_shift_mm": float(np.linalg.norm(r.displacement, axis=1).max()) * mm,
            "targets_spread_mm": None if s is None else s.spread * mm,
            "suggestion": None
            if s is None
            else {"label": "NextPoint", "expected_spread_mm": s.expected * mm, "spread_mm": s.spread * mm},
            "warning": r.warning,
            "update_ms": seconds * 1e3,
            "timings_ms": {k: v for k, v in r.seconds.items() if k.endswith("_ms")},  # (the fit's parts)
            "weights": [float(w) for w in r.weights],
        }

    # -- keeping the state -------------------------------------------------------------------

    def _push(self, **changes) -> None:
        self._history.append(self._state)
        del self._history[:-HISTORY]
        s = self._state
        self._state = _State(
            changes.get("labels", s.labels),
            changes.get("positions", s.positions),
            changes.get("touches", s.touches),
            changes.get("scan", s.scan),
        )

    def _checked(self, labels, positions, what: str) -> tuple[list[str], np.ndarray]:
        """Labels and finite positions inside the body's reach, or an InputError naming the point."""
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        labels = [str(label) for label in labels]
        if len(labels) != len(positions):
            raise InputError(f"{what}: {len(labels)} labels for {len(positions)} points")
        long = [label for label in labels if len(label.encode("utf-8")) > LABEL_BYTES]
        if long:
            raise InputError(
                f"{what}: label {long[0][:40]!r}... is longer than {LABEL_BYTES} bytes (an OpenIGTLink point's name); "
                f"shorten it"
            )
        seen = set()
        twice = next((label for label in labels if label in seen or seen.add(label)), None)
        if twice is not None:
            raise InputError(f"{what}: label {twice!r} is given twice; labels pair points: give each its own")
        bad = np.flatnonzero(~np.isfinite(positions).all(axis=1))
        if len(bad):
            raise InputError(f"{what}: point {labels[bad[0]]!r} is not a number (NaN or inf); measure it again")
        lo, hi = self._box
        out = np.flatnonzero(((positions < lo) | (positions > hi)).any(axis=1))
        if len(out):
            raise InputError(
                f"{what}: point {labels[out[0]]!r} at {np.round(positions[out[0]] * 1e3, 1).tolist()} mm is more than "
                f"{OUTSIDE_BODY * 1e3:g} mm outside the atlas's brain: another frame (RAS/LPS), unit or patient?"
            )
        return labels, positions
