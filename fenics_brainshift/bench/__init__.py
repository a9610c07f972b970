"""Run time against error: `brainshift bench` and benchmarks/time_vs_error.py."""

from .commands import atlas_arguments
from .report import machine_line
from .sweep import run_sweep

__all__ = ["atlas_arguments", "machine_line", "run_sweep"]
