"""Small validators for scene values: each raises InputError naming the field."""

from __future__ import annotations

import difflib
import math
from typing import Any

from ..errors import InputError


def number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{where} must be a finite number (got {value!r})")
    return float(value)


def positive(where: str, value: Any) -> float:
    value = number(where, value)
    if value <= 0:
        raise InputError(f"{where} must be > 0 (got {value:g})")
    return value


def non_negative(where: str, value: Any) -> float:
    value = number(where, value)
    if value < 0:
        raise InputError(f"{where} must be >= 0 (got {value:g})")
    return value


def vector3(where: str, value: Any) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise InputError(f"{where} must be a list of 3 numbers such as [0, 0, -9.81] (got {value!r})")
    return tuple(number(f"{where}[{i}]", v) for i, v in enumerate(value))  # type: ignore[return-value]


def choice(where: str, value: Any, options: tuple[str, ...]) -> str:
    if value not in options:
        raise InputError(f"{where} must be one of {', '.join(options)} (got {value!r})")
    return value


def integer(where: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise InputError(f"{where} must be an integer >= {minimum} (got {value!r})")
    return value


def did_you_mean(name: str, known) -> str:
    """ " did you mean 'x'?" for the closest of ``known`` to a mistyped ``name``, or "": the
    same name in another case first ('g' for 'G', which difflib finds no closer than 'E')."""
    same = [str(k) for k in known if str(k).lower() == str(name).lower()]
    close = same or difflib.get_close_matches(str(name), [str(k) for k in known], n=1, cutoff=0.6)
    return f" did you mean '{close[0]}'?" if close else ""
