"""fenics-brainshift: intraoperative brain shift from gravity and draining CSF, with DOLFINx.

The public API (see docs/api.md)::

    from fenics_brainshift import load_scene, run, Simulation
    result = run(load_scene("cube"), out="out_cube")   # or out=None: write nothing
    result.displacement                                  # a DOLFINx Function (m)

Names are imported on first use, so reading a scene or asking for the version does not
start DOLFINx.
"""

from importlib import import_module

from .version import __version__

_API = {
    "Scene": "scene",
    "load_scene": "scene",
    "scene_from_dict": "scene",
    "InputError": "errors",
    "SolverError": "errors",
    "BrainshiftError": "errors",
    "run": "runner",
    "Result": "runner",
    "Simulation": "runner",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    if name in _API:
        return getattr(import_module(f".{_API[name]}", __name__), name)
    raise AttributeError(f"module 'fenics_brainshift' has no attribute '{name}'")
