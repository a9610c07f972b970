"""The deformed mesh a warp follows: a run's last state, or points, tetrahedra and a
displacement given directly (RAS mm)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..images.frames import LPS_TO_RAS
from ..outputs.files import RunLock
from ..outputs.run_folder import read_last_state, read_saved_state, run_status


@dataclass
class DeformedMesh:
    """A run's mesh and final displacement in the image's RAS millimetres."""

    points: np.ndarray  # (n, 3) reference positions, RAS mm
    tets: np.ndarray  # (m, 4), the tissue still present
    displacement: np.ndarray  # (n, 3), RAS mm
    removed: np.ndarray | None = None  # (r, 4) the cells a resection took (the cavity's, before the shift)

    @classmethod
    def from_run(cls, run_dir: str | Path, mesh_frame: str = "RAS") -> DeformedMesh:
        """The last state a run wrote (RUN_DIR/displacement.xdmf; metres, the scene's frame), or
        of a run that was killed, its last complete one (RUN_DIR/last_state.npz)."""
        points, tets, u, tissue = read_run_state(Path(run_dir))
        removed = None
        if tissue is not None:  # a resection: the removed cells are not there any more
            present = np.asarray(tissue) >= 0.5
            tets, removed = tets[present], np.asarray(tets[~present], dtype=np.int64)
        flip = LPS_TO_RAS if mesh_frame.upper() == "LPS" else np.eye(3)
        return cls(1e3 * points[:, :3] @ flip, np.asarray(tets, dtype=np.int64), 1e3 * u[:, :3] @ flip, removed)


def killed_run_time(run_dir: Path) -> float | None:
    """The time of the last complete state of a run that was killed (summary.json "running", no
    process holding its folder, last_state.npz readable); None for any other folder."""
    if run_status(run_dir) != "running" or RunLock.holder(run_dir) is not None:
        return None
    try:
        return read_saved_state(run_dir)[4]
    except (OSError, ValueError, KeyError):
        return None


def read_run_state(run_dir: Path):
    """(points, tetrahedra, displacement, tissue) of the state a warp follows, or one line that
    says why there is none."""
    xdmf = run_dir / "displacement.xdmf"
    status = run_status(run_dir)
    if status == "running":
        holder = RunLock.holder(run_dir)
        if holder is not None:
            raise InputError(f"RUN_DIR: the run in '{run_dir}' is still running ({holder}); wait for it to end")
        try:  # killed: its last complete state was saved whole
            return read_saved_state(run_dir)[:4]
        except (OSError, ValueError, KeyError):
            raise InputError(
                f"RUN_DIR: the run in '{run_dir}' was killed before it saved a complete state (summary.json "
                f'says "running", no last_state.npz); run it again'
            ) from None
    if not xdmf.is_file():
        raise InputError(
            f"RUN_DIR: no displacement.xdmf in '{run_dir}'; run a scene with --out and "
            f'[output] fields including "displacement" first'
        )
    try:
        return read_last_state(xdmf)
    except (KeyError, StopIteration):
        if status not in (None, "ok"):  # stopped or interrupted before its first output
            raise InputError(
                f"RUN_DIR: the run in '{run_dir}' wrote no state (summary.json: {status}); run it again"
            ) from None
        problem = f"'{xdmf}' has no displacement field; add \"displacement\" to [output] fields and run again"
    except Exception as exc:  # a truncated .h5 or half an .xdmf (h5py, meshio, XML errors)
        problem = (
            f"'{xdmf.name}' or its .h5 in '{run_dir}' cannot be read ({type(exc).__name__}: "
            f"{str(exc)[:120]}); damaged or incomplete: run the scene again"
        )
    try:  # the same last state, saved whole beside the series
        return read_saved_state(run_dir)[:4]
    except (OSError, ValueError, KeyError):
        raise InputError(f"RUN_DIR: {problem}") from None
