"""Shared helpers: small scenes built from dictionaries, and MPI awareness."""

from __future__ import annotations

import copy
import os
import shutil
from pathlib import Path

import pytest
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
COMM = MPI.COMM_WORLD


def pytest_configure(config):
    """`make test-serial` runs the files on workers (pytest-xdist). They are started by this
    process after the import above started MPI here as a singleton, which put its own PMIx
    server's address into the process's environment (C's, not os.environ's); a worker started
    with it takes that server for an mpirun of its own: every mpirun it starts then ends with
    exit 1 and not a word, and the package's under-mpirun checks say yes. The workers get the
    environment this process was started with."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None and getattr(config.option, "numprocesses", None):
        _forget_variables_set_since_start()


def _forget_variables_set_since_start() -> None:
    """Unset every variable of C's environment that os.environ (read at start) does not hold."""
    import ctypes

    environ = ctypes.POINTER(ctypes.c_char_p).in_dll(ctypes.CDLL(None), "environ")
    names, k = [], 0
    while environ[k] is not None:
        names.append(os.fsdecode(environ[k].split(b"=", 1)[0]))
        k += 1
    for name in names:
        if name not in os.environ:
            os.unsetenv(name)


def column_dict(
    layers: int, degree: int = 1, height: float = 0.1, width: float = 0.02, gravity=(0.0, 0.0, -9.81), **sections
) -> dict:
    """A laterally confined column: bottom clamped, sides sliding (rollers), 1 x 1 x layers
    hexahedra split into tetrahedra. The analytic answer is the 1-D uniaxial-strain column."""
    eps = 1e-9
    data = {
        "name": "column",
        "mesh": {"shape": "box", "size": [width, width, height], "cells": [1, 1, layers]},
        "material": {"E": 5000.0, "nu": 0.3, "density": 1000.0},
        "gravity": {"vector": list(gravity)},
        "fixed": [
            {"where": f"z < {eps}", "axes": "xyz"},
            {"where": f"x < {eps} or x > {width - eps}", "axes": "x"},
            {"where": f"y < {eps} or y > {width - eps}", "axes": "y"},
        ],
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
        "element": {"degree": degree},
        "probes": {"top": [0.0, 0.0, height]},
    }
    for key, value in sections.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            data[key] = {**data[key], **value}
        else:
            data[key] = copy.deepcopy(value)
    return data


def decay_per_step(q, span: int = 10) -> float:
    """Measured |lambda| of the dominant complex pair in a sampled oscillation q_n.

    For q_n = Re(c lambda^n), the determinant D_n = q_{n+1} q_{n-1} - q_n^2 equals
    -|c|^2 |lambda|^(2n) sin^2(arg lambda), so |lambda| = (D_N / D_{N-span})^(1/(2 span))."""
    import numpy as np

    q = np.asarray(q, dtype=float)
    D = q[2:] * q[:-2] - q[1:-1] ** 2
    return float((D[-1] / D[-1 - span]) ** (1.0 / (2 * span)))


def lowest_mode(model):
    """(omega, phi) of a Model's lowest mode, K phi = omega^2 M phi with its supports, by inverse
    iteration (for the tests' columns the next mode is 3x higher: 40 iterations converge far
    below round-off); the solver of K with supports is returned too, for more solves."""
    import numpy as np
    from dolfinx.fem.petsc import set_bc

    from fenics_brainshift.linalg import LinearSolver

    M = model.assemble(model.mass_form(), with_bcs=False)
    K = model.assemble(model.stiffness_form(), with_bcs=False)
    solver = LinearSolver(model.assemble(model.stiffness_form(), with_bcs=True), "cholesky", name="modes")
    x, b = K.createVecRight(), K.createVecRight()
    x.set(1.0)
    set_bc(x, model.bcs)
    for _ in range(40):
        M.mult(x, b)
        set_bc(b, model.bcs)
        solver.solve(b, x)
        x.scale(1.0 / x.norm())
    Kx, Mx = K.createVecRight(), K.createVecRight()
    K.mult(x, Kx)
    M.mult(x, Mx)
    return float(np.sqrt(x.dot(Kx) / x.dot(Mx))), x, solver


def mpirun(ranks: int = 2) -> list[str]:
    exe = shutil.which("mpirun") or shutil.which("mpiexec")
    if exe is None:
        pytest.fail("mpirun not found: install openmpi-bin (scripts/install.sh does)")
    return [exe, "-n", str(ranks), "--oversubscribe"]  # a one-core machine runs two ranks too


def subprocess_env() -> dict:
    env = dict(os.environ)
    env.setdefault("OMPI_ALLOW_RUN_AS_ROOT", "1")
    env.setdefault("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
    env["OMP_NUM_THREADS"] = "1"
    return env


def high_water_mb() -> float:
    """This process's peak resident memory as the kernel's status file says it (VmHWM, kB)."""
    status = Path("/proc/self/status").read_text()
    return int(next(line.split()[1] for line in status.splitlines() if line.startswith("VmHWM:"))) / 1024


def run_group(cmd: list[str], timeout: float, **kwargs):
    """subprocess.run(cmd, capture_output=True, text=True), but on timeout the command is
    terminated, mpirun's ranks with it (subprocess.run kills mpirun alone, and left two ranks
    spinning for 40 minutes of a CI run), then its group killed, and the test fails with what
    the command had said."""
    import signal
    import subprocess

    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True, **kwargs
    )
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.terminate()  # mpirun passes SIGTERM on to its ranks (they are not in its group)
        try:
            out, err = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate()
        pytest.fail(
            f"{' '.join(map(str, cmd[:6]))} ... ran past {timeout:g} s; its last words:\n{out[-1500:]}\n{err[-3000:]}"
        )
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


@pytest.fixture
def serial_only():
    if COMM.size > 1:
        pytest.skip("runs its own subprocesses; only meaningful in the serial pass")


@pytest.fixture
def shared_tmp(tmp_path) -> Path:
    """tmp_path of rank 0, the same folder on every rank (each rank's own tmp_path differs)."""
    return Path(COMM.bcast(str(tmp_path), root=0))
