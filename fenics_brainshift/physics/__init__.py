"""Physics: material forms, gravity and the exact clipped hydrostatic load, supports,
resection, and the model that holds them. Takes plain values, never a scene."""

from .fluid import FluidLoad, FluidSettings
from .gravity import GravityLoad, total_force
from .hydrostatic import HydrostaticLoad, hydrostatic_load
from .material import LinearElastic, lame_parameters
from .model import Model
from .resection import Cut, Tissue
from .supports import Support

__all__ = [
    "Cut",
    "FluidLoad",
    "FluidSettings",
    "GravityLoad",
    "HydrostaticLoad",
    "LinearElastic",
    "Model",
    "Support",
    "Tissue",
    "hydrostatic_load",
    "lame_parameters",
    "total_force",
]
