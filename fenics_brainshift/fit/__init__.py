"""Calibration to the operating room: fit the CSF level, the stiffness and the head pose to
intra-operative points (`brainshift fit`)."""

from ..images.targets import Target, read_target
from .calibrate import FitResult, fit
from .forward import ForwardModel
from .parameters import NAMES, Parameter, fit_parameters, scene_changes

__all__ = [
    "NAMES",
    "FitResult",
    "ForwardModel",
    "Parameter",
    "Target",
    "fit",
    "fit_parameters",
    "read_target",
    "scene_changes",
]
