"""What a process has held: the number a results file or atlas.json reports as its peak memory."""

from __future__ import annotations

from pathlib import Path


def peak_memory_mb() -> float:
    """The largest resident memory this process has held so far, MB: the kernel's VmHWM. Not
    getrusage's ru_maxrss, which Linux carries over from the parent through fork and exec (a
    command started by a larger process would report the parent's peak)."""
    try:
        status = Path("/proc/self/status").read_text()
        return int(next(line.split()[1] for line in status.splitlines() if line.startswith("VmHWM:"))) / 1024
    except (OSError, StopIteration, ValueError):  # (not Linux)
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
