"""What a process has held: the number a results file or atlas.json reports as its peak memory."""

from __future__ import annotations


def peak_memory_mb() -> float:
    """The largest resident memory this process has held so far, MB (Linux counts in kB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
