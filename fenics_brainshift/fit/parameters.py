"""What a calibration can fit: the CSF level, the stiffness, the head pose.

- ``fluid.level``: the level the CSF has drained to (m along up), the settled state's level;
  bounds: the body's lowest and highest surface points.
- ``material.G``: the shear modulus (Pa, nu kept); bounds: a tenth to ten times the scene's.
- ``gravity.angle_x`` / ``angle_y`` / ``angle_z``: the head pose as a rotation of the scene's
  gravity vector about the scene's x / y / z axis (degrees; applied x, then y, then z);
  bounds: +-30 degrees.

A Parameter knows its prior (the scene's value), bounds and typical size; ``scene_changes``
turns fitted values into the scene's own keys (the fitted TOML).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputError
from ..scene.checks import did_you_mean

if TYPE_CHECKING:
    from ..scene import Scene

NAMES = ("fluid.level", "material.G", "gravity.angle_x", "gravity.angle_y", "gravity.angle_z")
MAX_ANGLE = 30.0  # degrees
G_RANGE = 10.0  # G within [G / 10, 10 G] of the scene's


@dataclass(frozen=True)
class Parameter:
    """A fitted parameter: its name (``fluid.level``, ``material.G``, ``gravity.angle_x`` ...),
    the scene's value (the prior), its bounds, a typical size and its unit."""

    name: str
    prior: float
    lower: float
    upper: float
    scale: float  # a typical size, for the optimiser's variable scaling
    unit: str


def check_names(names: list[str]) -> None:
    """Known, each once, at least one (before anything is built)."""
    if not names:
        raise InputError(f"--params: name at least one of {', '.join(NAMES)}")
    for i, name in enumerate(names):
        if name not in NAMES:
            raise InputError(
                f"--params: '{name}' cannot be fitted;{did_you_mean(name, NAMES)} choose from {', '.join(NAMES)}"
            )
        if name in names[:i]:
            raise InputError(f"--params: '{name}' is given twice")


def fit_parameters(scene: Scene, names: list[str], heights: tuple[float, float]) -> list[Parameter]:
    """The Parameters named (``--params``), priors from the scene; heights: the lowest and
    highest surface point along up (m), the level's bounds."""
    check_names(names)
    out = []
    for name in names:
        if name == "fluid.level":
            if scene.fluid is None or scene.fluid.volume is not None:
                raise InputError("--params fluid.level: the scene needs [fluid] with a level schedule (not a volume)")
            prior = final_level(scene)
            lower, upper = heights
            out.append(Parameter(name, float(np.clip(prior, lower, upper)), lower, upper, 0.01, "m"))
        elif name == "material.G":
            G = scene.material.G
            out.append(Parameter(name, G, G / G_RANGE, G * G_RANGE, G, "Pa"))
        else:
            out.append(Parameter(name, 0.0, -MAX_ANGLE, MAX_ANGLE, 5.0, "deg"))
    return out


def final_level(scene) -> float:
    """The scene's level once drained (m): at its settled time."""
    return float(scene.fluid.level(scene.settled_time))


def rotated_gravity(g0, values: dict[str, float]) -> np.ndarray:
    """The scene's gravity rotated by the pose angles in ``values`` (degrees)."""
    angles = [values.get(f"gravity.angle_{a}", 0.0) for a in "xyz"]
    return Rotation.from_euler("xyz", angles, degrees=True).apply(np.asarray(g0, dtype=float))


def scene_changes(scene: Scene, values: dict[str, float]) -> dict[str, object]:
    """{"section.key": value} for the scene's TOML: the level plateau after the drain, G, and
    the rotated gravity vector."""
    changes: dict[str, object] = {}
    if "fluid.level" in values:
        h, old = values["fluid.level"], final_level(scene)
        # the breakpoints at the final value (the plateau after the drain) move to the fitted one
        changes["fluid.level"] = [[t, h if abs(v - old) <= 1e-12 else v] for t, v in scene.fluid.level.points]
    if "material.G" in values:
        changes["material.G"] = values["material.G"]
        changes["material.E"] = None  # G and nu define the material: a given E would contradict G
    if any(k.startswith("gravity.angle") for k in values):
        changes["gravity.vector"] = [float(c) for c in rotated_gravity(scene.gravity.vector, values)]
    return changes
