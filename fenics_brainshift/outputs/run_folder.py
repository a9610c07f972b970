"""A finished run's folder as later commands read it: its status (summary.json) and its last
state (displacement.xdmf, or last_state.npz, which a killed run leaves readable), without
DOLFINx."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def read_last_state(xdmf: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """(points, tetrahedra, displacement, tissue or None) at the last time of a run's XDMF."""
    import meshio

    with meshio.xdmf.TimeSeriesReader(str(xdmf)) as reader:
        points, cells = reader.read_points_cells()
        point_data, cell_data = {}, {}
        for k in range(reader.num_steps):
            _, pd, cd = reader.read_data(k)
            point_data.update(pd)
            cell_data.update(cd)
    tets = next(c.data for c in cells if c.type == "tetra")
    tissue = cell_data.get("tissue")
    return points, tets, point_data["displacement"], (np.asarray(tissue[0]).ravel() if tissue else None)


def read_saved_state(folder: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, float]:
    """(points, tetrahedra, displacement, tissue or None, time) of FOLDER/last_state.npz, the
    run's latest complete state (outputs/last_state.py). Raises OSError or ValueError when it
    is missing or damaged."""
    import zipfile

    try:
        with np.load(Path(folder) / "last_state.npz", allow_pickle=False) as saved:
            tissue = saved["tissue"] if "tissue" in saved.files else None
            state = (saved["points"], saved["tetrahedra"], saved["displacement"], tissue, float(saved["time"]))
    except (zipfile.BadZipFile, EOFError, KeyError) as exc:  # cut short, or not this file
        raise ValueError(f"last_state.npz is damaged ({type(exc).__name__})") from None
    points, tets, u = state[:3]
    if points.ndim != 2 or points.shape[1] != 3 or u.shape != points.shape or tets.ndim != 2 or tets.shape[1] != 4:
        raise ValueError("its arrays do not fit together")
    named = len(tets) == 0 or 0 <= tets.min() <= tets.max() < len(points)
    if not (np.isfinite(points).all() and np.isfinite(u).all() and named):
        raise ValueError("its numbers are not finite or its tetrahedra name no vertex")
    tissue = state[3]
    if tissue is not None and (tissue.shape != (len(tets),) or not np.isfinite(tissue).all()):
        raise ValueError("its tissue is not one number a tetrahedron")
    return state


def run_status(run_dir: Path) -> str | None:
    """summary.json's status of a run folder ("ok", "running", "interrupted", "stopped: ..."),
    or None without one."""
    try:
        return str(json.loads((run_dir / "summary.json").read_text()).get("status"))
    except (OSError, ValueError, AttributeError):
        return None
