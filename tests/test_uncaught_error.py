"""errors.abort_on_uncaught: under mpirun, a bug that raises on one rank ends the job with its
traceback, instead of leaving the other rank waiting in a collective for ever (a 2-rank demo
hung for 15 minutes of a CI run with its last words unread)."""

from __future__ import annotations

import sys
import time

import pytest

from conftest import mpirun, run_group, subprocess_env

pytestmark = pytest.mark.usefixtures("serial_only")

# rank 1 fails alone; rank 0 waits for it in a barrier
ONE_RANK_FAILS = """
from mpi4py import MPI
from fenics_brainshift import logs
logs.configure("WARNING")
if MPI.COMM_WORLD.rank == 1:
    raise RuntimeError("a bug on rank 1 alone")
MPI.COMM_WORLD.barrier()
print("rank", MPI.COMM_WORLD.rank, "passed the barrier", flush=True)
"""


def test_an_error_on_one_rank_ends_the_job_with_its_traceback():
    began = time.perf_counter()
    proc = run_group(mpirun() + [sys.executable, "-c", ONE_RANK_FAILS], 60, env=subprocess_env())
    assert proc.returncode != 0
    assert "RuntimeError: a bug on rank 1 alone" in proc.stderr
    assert "aborting every rank" in proc.stderr and "passed the barrier" not in proc.stdout
    assert time.perf_counter() - began < 30


def test_on_one_rank_the_hook_leaves_the_exit_as_python_makes_it():
    proc = run_group([sys.executable, "-c", ONE_RANK_FAILS.replace("== 1", "== 0")], 60, env=subprocess_env())
    assert proc.returncode == 1 and "RuntimeError: a bug on rank 1 alone" in proc.stderr
    assert "aborting" not in proc.stderr
