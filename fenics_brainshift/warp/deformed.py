"""The deformed mesh a warp follows: a run's last state, or points, tetrahedra and a
displacement given directly (RAS mm)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..images.frames import LPS_TO_RAS
from ..outputs.run_folder import read_last_state, run_status


@dataclass
class DeformedMesh:
    """A run's mesh and final displacement in the image's RAS millimetres."""

    points: np.ndarray  # (n, 3) reference positions, RAS mm
    tets: np.ndarray  # (m, 4), the tissue still present
    displacement: np.ndarray  # (n, 3), RAS mm

    @classmethod
    def from_run(cls, run_dir: str | Path, mesh_frame: str = "RAS") -> DeformedMesh:
        """The last state a run wrote (RUN_DIR/displacement.xdmf; metres, the scene's frame)."""
        xdmf = Path(run_dir) / "displacement.xdmf"
        status = run_status(Path(run_dir))
        if status == "running":  # killed, or still running: its files are incomplete
            raise InputError(
                f"RUN_DIR: the run in '{run_dir}' did not finish (summary.json says \"running\": "
                f"killed, or still running); run it again, or wait for it"
            )
        if not xdmf.is_file():
            raise InputError(
                f"RUN_DIR: no displacement.xdmf in '{run_dir}'; run a scene with --out and "
                f'[output] fields including "displacement" first'
            )
        try:
            points, tets, u, tissue = read_last_state(xdmf)
        except (KeyError, StopIteration):
            if status not in (None, "ok"):  # stopped or interrupted before its first output
                raise InputError(
                    f"RUN_DIR: the run in '{run_dir}' wrote no state (summary.json: {status}); run it again"
                ) from None
            raise InputError(
                f"RUN_DIR: '{xdmf}' has no displacement field; add \"displacement\" to [output] fields and run again"
            ) from None
        except Exception as exc:  # a truncated .h5 or half an .xdmf (h5py, meshio, XML errors)
            raise InputError(
                f"RUN_DIR: '{xdmf.name}' or its .h5 in '{run_dir}' cannot be read ({type(exc).__name__}: "
                f"{str(exc)[:120]}); damaged or incomplete: run the scene again"
            ) from None
        if tissue is not None:  # a resection: the removed cells are not there any more
            tets = tets[np.asarray(tissue) >= 0.5]
        flip = LPS_TO_RAS if mesh_frame.upper() == "LPS" else np.eye(3)
        return cls(1e3 * points[:, :3] @ flip, np.asarray(tets, dtype=np.int64), 1e3 * u[:, :3] @ flip)
