"""JSON as strict JSON: every file this package writes parses with any reader. Python's json
writes NaN and Infinity, which are not JSON (a point-to-surface update.json with a NaN in it
could not be read back); here a non-finite number becomes null and the document says where and
what it was ("non_finite": {"residual_mm[3]": "nan"})."""

from __future__ import annotations

import json
import math

import numpy as np


def dumps(data: dict, indent: int | None = 2) -> str:
    """``data`` (dicts, lists, numbers, strings, numpy values) as strict JSON text."""
    replaced: dict[str, str] = {}
    plain = _finite(data, "", replaced)
    if replaced:
        plain["non_finite"] = {**plain.get("non_finite", {}), **replaced}
    return json.dumps(plain, indent=indent, allow_nan=False)


def _finite(value, where: str, replaced: dict):
    if isinstance(value, np.ndarray):
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, dict):
        return {str(k): _finite(v, f"{where}.{k}" if where else str(k), replaced) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v, f"{where}[{i}]", replaced) for i, v in enumerate(value)]
    if isinstance(value, float) and not math.isfinite(value):
        replaced[where] = str(value)
        return None
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    raise TypeError(f"not JSON serialisable: {where}: {type(value).__name__}")
