"""Scenes: every input of a run as small validated dataclasses, from TOML or built in Python.

Imports no DOLFINx: a scene can be read and checked anywhere. Units are SI (m, kg, s, Pa)
everywhere; only a mesh *file* may be given in other length units (``[mesh] unit``).
"""

from .body import FixedRegion, Material, MeshSpec, Removal, Swelling
from .loads import Fluid, Gravity
from .numerics import Damping, Element, Output, SolverConfig, TimeScheme
from .predicates import Predicate, PredicateError, parse_predicate
from .scene import Scene
from .schedule import Schedule
from .toml import apply_override, load_scene, scene_from_dict

__all__ = [
    "Damping",
    "Element",
    "FixedRegion",
    "Fluid",
    "Gravity",
    "Material",
    "MeshSpec",
    "Output",
    "Predicate",
    "PredicateError",
    "Removal",
    "Scene",
    "Schedule",
    "SolverConfig",
    "Swelling",
    "TimeScheme",
    "apply_override",
    "load_scene",
    "parse_predicate",
    "scene_from_dict",
]
