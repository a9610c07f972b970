"""conftest.run_group, the tests' way to run mpirun: a command past its timeout is stopped with
its ranks (subprocess.run's timeout killed mpirun alone, and two ranks went on spinning for 40
minutes of a CI run), and the test fails with what it had said."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from conftest import mpirun, run_group, subprocess_env

pytestmark = pytest.mark.usefixtures("serial_only")
SLEEPER = "print('started', flush=True); import time; time.sleep(61.5)"


def test_a_command_past_its_timeout_is_stopped_with_its_ranks():
    began = time.perf_counter()
    with pytest.raises(pytest.fail.Exception, match=r"ran past 3 s; its last words:\n(.|\n)*started"):
        run_group(mpirun() + [sys.executable, "-c", SLEEPER], 3, env=subprocess_env())
    time.sleep(1.0)
    assert not _running("time.sleep(61.5)"), "ranks left running"
    assert time.perf_counter() - began < 30


def _running(text: str) -> list[str]:
    """The pids whose command line holds ``text`` (/proc: procps is not on every machine)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if text in cmdline.read_bytes().replace(b"\0", b" ").decode(errors="replace"):
                found.append(cmdline.parent.name)
        except OSError:  # gone meanwhile
            pass
    return found


def test_a_command_within_its_timeout_returns_as_subprocess_run_would():
    done = run_group([sys.executable, "-c", "import sys; print(42); sys.exit(3)"], 60)
    assert (done.returncode, done.stdout.strip()) == (3, "42")
