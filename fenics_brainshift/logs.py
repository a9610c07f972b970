"""Logging that lets rank 0 speak (other ranks only when asked with all_ranks=True)."""

from __future__ import annotations

import logging

LOGGER_NAME = "fenics_brainshift"


class _RankZero(logging.Filter):
    def __init__(self, rank: int):
        super().__init__()
        self.rank = rank

    def filter(self, record: logging.LogRecord) -> bool:
        return self.rank == 0


def get_logger(name: str = "") -> logging.Logger:
    return logging.getLogger(f"{LOGGER_NAME}.{name}" if name else LOGGER_NAME)


def configure(level: str = "INFO", all_ranks: bool = False, one_process: bool = False) -> None:
    """Install one stderr handler on the package logger (idempotent), and, as every entry
    point (the CLI, the demos) calls this first, the hook that aborts every rank on an error
    no one caught (errors.abort_on_uncaught); one_process: a command that starts no MPI."""
    rank = 0
    if not one_process:
        from mpi4py import MPI

        from .errors import abort_on_uncaught

        abort_on_uncaught()
        rank = MPI.COMM_WORLD.rank
    logger = get_logger()
    logger.setLevel(level.upper())
    for handler in list(logger.handlers):
        logger.removeHandler(handler)
    handler = logging.StreamHandler()
    prefix = f"[rank {rank}] " if all_ranks else ""
    handler.setFormatter(logging.Formatter(f"{prefix}%(message)s"))
    if not all_ranks:
        handler.addFilter(_RankZero(rank))
    logger.addHandler(handler)
    logger.propagate = False
    # The form compiler's C build logs through the root logger at INFO and would set up a
    # root handler of its own (basicConfig) on first use; a root handler here makes that a
    # no-op, and the root level keeps the compile chatter out of the user's terminal.
    root = logging.getLogger()
    if not root.handlers:
        root.addHandler(logging.NullHandler())
    root.setLevel(logging.WARNING)


def _not_compiler_chatter(record: logging.LogRecord) -> bool:
    """Drop the C build's INFO lines (the JIT of forms goes through setuptools' distutils,
    which logs each gcc command line to the root logger and lowers its level to INFO)."""
    return record.levelno >= logging.WARNING or "distutils" not in record.pathname


def quiet_compiler() -> None:
    """Keep the form compiler's gcc command lines out of the user's terminal (idempotent)."""
    root = logging.getLogger()
    if _not_compiler_chatter not in root.filters:
        root.addFilter(_not_compiler_chatter)
