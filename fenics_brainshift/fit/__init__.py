"""Calibration to the operating room: fit the CSF level, the stiffness and the head pose to
intra-operative points (`brainshift fit`)."""
from .calibrate import FitResult, fit
from .forward import ForwardModel
from .parameters import NAMES, Parameter, parameters, scene_changes
from .targets import Target, read_target

__all__ = ["NAMES", "FitResult", "ForwardModel", "Parameter", "Target", "fit", "parameters", "read_target",
           "scene_changes"]
