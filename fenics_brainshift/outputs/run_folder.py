"""A finished run's folder as later commands read it: its status (summary.json) and its last
state (displacement.xdmf), without DOLFINx."""

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


def run_status(run_dir: Path) -> str | None:
    """summary.json's status of a run folder ("ok", "running", "interrupted", "stopped: ..."),
    or None without one."""
    try:
        return str(json.loads((run_dir / "summary.json").read_text()).get("status"))
    except (OSError, ValueError, AttributeError):
        return None
