"""Run time against error: `brainshift bench` and benchmarks/time_vs_error.py."""

from .report import machine_line
from .sweep import run_sweep

__all__ = ["machine_line", "run_sweep"]
