"""The peak memory a command reports (atlas.json, prepare.json) is its own: a process that
allocates a known amount reports about that, even when started by a process that held far more
(getrusage's ru_maxrss carries the parent's peak through fork and exec on Linux)."""

from __future__ import annotations

import subprocess
import sys

from conftest import ROOT

CHILD = """
import numpy as np
from fenics_brainshift.memory import peak_memory_mb
held = np.ones(40_000_000)  # 305 MB, every page touched
print(peak_memory_mb())
"""

PARENT = """
import subprocess, sys
import numpy as np
big = np.ones(150_000_000)  # 1144 MB, touched, then let go before the child starts
del big
print(subprocess.run([sys.executable, "-c", sys.argv[1]], capture_output=True, text=True, check=True).stdout)
"""


def test_a_process_reports_its_own_peak_not_its_parents():
    out = subprocess.run(
        [sys.executable, "-c", PARENT, CHILD], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout
    peak = float(out.split()[-1])
    assert 305 <= peak <= 305 + 250, peak  # the array, and Python with NumPy (far below the parent's 1144 MB)
