"""What an atlas varies: the family of alternative scenarios (drain level x head pose), whose
settled states the update combines with convex weights, and the shrinking or swelling regions,
each a perturbation mode the update scales within bounds.

``--vary`` gives a key and its values, in the scene's own units:

    fluid.level=0.02,0.03,0.045     levels (m along up), or start:stop:count (0.01:0.05:5)
    gravity.angle_x=-10,0,10        head pose: the scene's gravity turned about x (degrees)
    swelling.N=-0.03,0.02           the bounds of a [[swelling]] region's volume change (N:
                                    its index 0, 1, ... in the scene; "brain" for the
                                    whole-brain mode of a scene without any)
    material.G=1500,4000            the bounds of the shear modulus (Pa): no modes of its own
                                    (u is proportional to 1/G in a linear body under fixed
                                    loads; follower loads make it approximate), the family's
                                    weights then sum to G0/G, between G0/HIGH and G0/LOW

Without ``--vary`` (a craniotomy): 14 levels, 5 mm apart, from 45 mm below the scene's final
level to 20 mm above it, the head turned by -12 to 12 degrees in steps of 6 about the two scene
axes that turn gravity most (5 x 5 poses): 350 settled states; each [[swelling]] region between
none and 1.5x its volume change, and, in a scene without any, the whole brain shrinking by up
to 4 % or swelling by up to 2 % (a hyperosmotic drug, oedema); G from a third to three times
the scene's. The range is wide because the linear modes stand in for what they do not hold:
a neo-Hookean brain's settled state is matched by a linear one 45 mm lower and twice as stiff
(`brainshift fit` finds that; with 25 mm below and G within 0.5-2x the update could not reach
it: 0.83 mm deep error against the fit's 0.29, benchmarks/results/update.md).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..scene.checks import did_you_mean

FAMILY_KEYS = ("fluid.level", "gravity.angle_x", "gravity.angle_y", "gravity.angle_z")
MAX_VALUES = 200  # values of one --vary key
MAX_MODES = 2000  # drain/pose scenarios of one atlas (the default has 350)
# what a mode costs on the 5 mm brain with the skull, one core (benchmarks/results/atlas_speed.md)
SECONDS_A_MODE = 1.3
DEFAULT_LEVELS = (-0.045, 0.020, 14)  # m about the scene's final level: below, above, count
DEFAULT_ANGLES = (-12.0, -6.0, 0.0, 6.0, 12.0)  # degrees, about each of two axes
WHOLE_BRAIN = ("brain", -0.04, 0.02)  # a scene without [[swelling]]: the whole body's bounds
MAX_ANGLE = 45.0  # degrees: past this a pose is another operation, not a variation


@dataclass(frozen=True)
class SwellingMode:
    """A region's perturbation mode: computed at the volume change `mode`, scaled in the update
    between `lower` and `upper` (volume changes; `prior`: the scene's own)."""

    name: str
    index: int | None  # the scene's [[swelling]] index, None for the added whole-brain region
    prior: float
    mode: float
    lower: float
    upper: float


def parse_vary(texts: list[str]) -> dict[str, list[float]]:
    """{"fluid.level": [...], ...} from --vary KEY=VALUES (checked for form, not for sense)."""
    out: dict[str, list[float]] = {}
    for text in texts:
        key, sep, values = text.partition("=")
        key = key.strip()
        if not sep or not values.strip():
            raise InputError(
                f"--vary '{text}': give KEY=VALUES, e.g. fluid.level=0.02,0.03,0.04 or "
                f"fluid.level=0.01:0.05:5 (start:stop:count)"
            )
        if key not in FAMILY_KEYS + ("material.G",) and not key.startswith("swelling."):
            raise InputError(
                f"--vary '{key}' cannot be varied;{did_you_mean(key, FAMILY_KEYS)} use "
                f"{', '.join(FAMILY_KEYS)}, material.G or swelling.N (a region's index)"
            )
        if key in out:
            raise InputError(f"--vary {key} is given twice")
        out[key] = _values(key, values)
    modes = int(np.prod([len(v) for k, v in out.items() if k in FAMILY_KEYS] or [0], dtype=float))
    if modes > MAX_MODES:
        hours = modes * SECONDS_A_MODE / 3600
        raise InputError(
            f"--vary: {modes:,} drain/pose scenarios (the product of the values given), at most {MAX_MODES}: "
            f"about {hours:,.0f} h at {SECONDS_A_MODE} s a mode on the 5 mm brain with the skull; give fewer "
            f"values (the default atlas has 14 levels x 25 poses)"
        )
    return out


def _values(key: str, text: str) -> list[float]:
    try:
        if ":" in text:
            start, stop, count = text.split(":")
            if int(count) < 1 or int(count) != float(count):
                raise ValueError
            if int(count) > MAX_VALUES:
                raise InputError(
                    f"--vary {key}={text}: {int(count):,} values, at most {MAX_VALUES} (each is a settled "
                    f"state to solve); give fewer"
                )
            values = list(np.linspace(float(start), float(stop), int(count)))
        else:
            values = [float(v) for v in text.split(",")]
            if len(values) > MAX_VALUES:
                raise InputError(f"--vary {key}: {len(values):,} values, at most {MAX_VALUES}; give fewer")
    except InputError:
        raise
    except ValueError:
        raise InputError(f"--vary {key}={text}: not a list of numbers (a,b,c) nor start:stop:count") from None
    if not all(np.isfinite(values)):
        raise InputError(f"--vary {key}={text}: every value must be a finite number")
    if key.startswith("swelling.") and (len(values) != 2 or not -1 < values[0] < values[1] < 1):
        raise InputError(
            f"--vary {key}={text}: give the region's lowest and highest volume change, "
            f"-1 < LOW < HIGH < 1 (e.g. -0.03,0.02)"
        )
    if key == "material.G" and (len(values) != 2 or not 0 < values[0] < values[1]):
        raise InputError(
            f"--vary material.G={text}: give the lowest and highest shear modulus in Pa, "
            f"0 < LOW < HIGH (e.g. 1500,6000)"
        )
    if len(set(values)) != len(values):
        raise InputError(f"--vary {key}={text}: a value is given twice")
    return [float(v) for v in values]


def family(scene, vary: dict[str, list[float]], heights: tuple[float, float]) -> list[dict[str, float]]:
    """The grid of (level, pose) scenarios: the values of --vary, and the defaults for the
    keys it does not give when it gives none of them; levels descending within each pose, as
    the fluid drains (each settled state starts from the last; with the skull a pose's first
    is solved from rest, and at the highest level, the brain borne by the fluid, it presses
    the skull least: on the 5 mm brain, 3 mm gap, turned -12 degrees, 6 Newton iterations
    against 31 from rest at the lowest; 8.9 a state over the pose against 13.2
    ascending, benchmarks/results/skull_atlas.md). heights: the body's lowest and highest surface point
    along up (m), the levels' range."""
    given = {k: v for k, v in vary.items() if k in FAMILY_KEYS}
    axes = dict(given) if given else _default_family(scene)
    if "fluid.level" in given:  # (the default levels are clipped to the body instead: clip_levels)
        if scene.fluid is None or scene.fluid.volume is not None:
            raise InputError("--vary fluid.level: the scene needs [fluid] with a level schedule (not a volume)")
        low, high = heights
        outside = [v for v in axes["fluid.level"] if not low - 1e-9 <= v <= high + 1e-9]
        if outside:
            raise InputError(
                f"--vary fluid.level: {outside[0]:g} m is not between the body's lowest and highest "
                f"point along up ({low:.4g} to {high:.4g} m; the scene's drained level "
                f"{_drained_level(scene):.4g} m): levels are heights along up in the scene's frame, "
                f"in metres (mm / 1000)"
            )
    for key in FAMILY_KEYS[1:]:
        if any(abs(v) > MAX_ANGLE for v in axes.get(key, [])):
            raise InputError(f"--vary {key}: angles are degrees within +-{MAX_ANGLE:g} of the scene's pose")
    keys = [k for k in FAMILY_KEYS if k in axes]  # the level last: it varies fastest
    keys = [k for k in keys if k != "fluid.level"] + (["fluid.level"] if "fluid.level" in keys else [])
    grid = [
        dict(zip(keys, combo))
        for combo in itertools.product(*(sorted(axes[k], reverse=k == "fluid.level") for k in keys))
    ]
    return grid or [{}]


def _drained_level(scene) -> float:
    return float(scene.fluid.level(scene.settled_time)) if scene.fluid.level else float("nan")


def _default_family(scene) -> dict[str, list[float]]:
    axes: dict[str, list[float]] = {}
    if scene.fluid is not None and scene.fluid.volume is None and scene.fluid.level:
        final = float(scene.fluid.level(scene.settled_time))
        below, above, count = DEFAULT_LEVELS
        axes["fluid.level"] = list(np.linspace(final + below, final + above, count))
    g = np.asarray(scene.gravity.vector, dtype=float)
    if np.linalg.norm(g) > 0:
        # the two scene axes about which a turn moves gravity most (|e x g| largest)
        turn = [np.linalg.norm(np.cross(np.eye(3)[i], g)) for i in range(3)]
        for i in sorted(np.argsort(turn)[-2:]):
            axes[f"gravity.angle_{'xyz'[i]}"] = list(DEFAULT_ANGLES)
    return axes


def clip_levels(grid: list[dict[str, float]], heights: tuple[float, float]) -> list[dict[str, float]]:
    """Default levels kept within the body (a level above its top is a full bath, below its
    bottom a dry body: each once)."""
    low, high = heights
    out, seen = [], set()
    for s in grid:
        s = dict(s)
        if "fluid.level" in s:
            s["fluid.level"] = float(np.clip(s["fluid.level"], low, high))
        key = tuple(sorted(s.items()))
        if key not in seen:
            seen.add(key)
            out.append(s)
    return out


def swelling_modes(scene, vary: dict[str, list[float]]) -> list[SwellingMode]:
    """One mode per [[swelling]] region (bounds from --vary swelling.N, else between none
    and 1.5x its volume change); the whole brain in a scene without any."""
    regions = list(scene.swelling)
    names = [getattr(r, "name", None) or str(i) for i, r in enumerate(regions)]
    asked = {k.split(".", 1)[1]: v for k, v in vary.items() if k.startswith("swelling.")}
    for name in asked:
        if name not in names and not (not regions and name == WHOLE_BRAIN[0]):
            known = names or [WHOLE_BRAIN[0]]
            raise InputError(
                f"--vary swelling.{name}: no such region;{did_you_mean(name, known)} the scene's are {', '.join(known)}"
            )
    if not regions:
        name, lower, upper = WHOLE_BRAIN
        lower, upper = asked.get(name, (lower, upper))
        return [SwellingMode(name, None, 0.0, lower if abs(lower) >= abs(upper) else upper, lower, upper)]
    out = []
    for i, (region, name) in enumerate(zip(regions, names)):
        theta, full = float(region.at(scene.settled_time)), float(region.volume_change)
        lower, upper = asked.get(name, (min(0.0, 1.5 * full), max(0.0, 1.5 * full)))
        if not lower <= theta <= upper:
            raise InputError(
                f"--vary swelling.{name}={lower:g},{upper:g}: the scene's own volume change "
                f"{theta:g} must lie within the bounds"
            )
        # the perturbation is computed at the bound farther from the scene's value
        mode = upper if upper - theta >= theta - lower else lower
        out.append(SwellingMode(name, i, theta, mode, lower, upper))
    return out


STIFFNESS_RANGE = (1.0 / 3.0, 3.0)  # default bounds of G, times the scene's (follower loads: 1/G is approximate)


def stiffness(scene, vary: dict[str, list[float]]) -> dict[str, float]:
    """{"G": the scene's, "lower", "upper"}: the shear modulus's bounds in the update."""
    G = float(scene.material.G)
    lower, upper = vary.get("material.G", [STIFFNESS_RANGE[0] * G, STIFFNESS_RANGE[1] * G])
    if not lower <= G <= upper:
        raise InputError(f"--vary material.G={lower:g},{upper:g}: the scene's own G = {G:g} Pa must lie within")
    return {"G": G, "lower": float(lower), "upper": float(upper)}
