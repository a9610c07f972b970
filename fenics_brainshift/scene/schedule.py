"""Values given as a number or as [[t, value], ...], piecewise linear in time."""

from __future__ import annotations

from ..errors import InputError
from .checks import number


class Schedule:
    """Piecewise linear in time: points (t, value), held constant before the first and after
    the last. A single number means constant."""

    __slots__ = ("points", "where")

    def __init__(self, points, where: str):
        self.where = where
        if isinstance(points, (int, float)) and not isinstance(points, bool):
            points = ((0.0, float(points)),)
        if not isinstance(points, (list, tuple)) or not points:
            raise InputError(f"{where} must be a number or a list of [time, value] pairs")
        pts = []
        for i, p in enumerate(points):
            if not isinstance(p, (list, tuple)) or len(p) != 2:
                raise InputError(f"{where}[{i}] must be a [time, value] pair (got {p!r})")
            pts.append((number(f"{where}[{i}] time", p[0]), number(f"{where}[{i}] value", p[1])))
        for i in range(1, len(pts)):
            if pts[i][0] <= pts[i - 1][0]:
                raise InputError(
                    f"{where}[{i}] time {pts[i][0]:g} s must be later than {pts[i - 1][0]:g} s (times must increase)"
                )
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
