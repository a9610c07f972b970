"""The paper's error measures (section IV-C and IV-D) for a simulated brain shift.

Three surfaces: PRE (pre-operative), INTRA (intra-operative, measured) and SIM (PRE moved by
the simulation: the same vertices in the same order, as the fine surface is written).

- Landmarks (IV-C): node A is the PRE vertex farthest along ``up`` (the most anterior point
  of a supine patient); node B the PRE vertex farthest along a second direction. The matching
  INTRA point is the one farthest along the same direction among INTRA vertices within
  ``search`` (laterally) of the simulated position (the paper's two assumptions). Regions:
  the points within ``radius`` of the line through the landmark along the direction and at
  most ``depth`` below it; their centroids reduce registration noise.
  d_MRI = p_intra - p_pre (eq. 22), d_MRI_bar = centroid_intra - centroid_pre (23),
  d_Sim = p_sim - p_pre (24), Error_i % = |(d_MRI_i - d_Sim_i) / d_MRI_i| (25), per axis and for
  the norm.
- Surface error (IV-D): INTRA and SIM heights along an axis, interpolated (scipy griddata,
  linear) on a grid of ``spacing`` over a rectangle of the two other axes; SIM - INTRA at each
  grid point: max, min, mean, median and mean absolute error.

Lengths are in the surfaces' units (metres after reading with a scale).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v)
    if n == 0:
        raise InputError("a direction must be a non-zero vector")
    return v / n


def region(points: np.ndarray, apex: np.ndarray, direction, radius: float, depth: float) -> np.ndarray:
    """Points within ``radius`` of the line through ``apex`` along ``direction`` and at most
    ``depth`` below the apex along it (the paper's regions A and B)."""
    d = _unit(direction)
    rel = points - apex
    along = rel @ d
    lateral = np.linalg.norm(rel - along[:, None] * d, axis=1)
    return (lateral < radius) & (along <= 1e-12) & (along >= -depth)


@dataclass
class Landmark:
    name: str
    index_pre: int
    p_pre: np.ndarray
    p_intra: np.ndarray
    p_sim: np.ndarray
    d_mri: np.ndarray
    d_mri_bar: np.ndarray
    d_sim: np.ndarray

    @staticmethod
    def error_percent(d_ref: np.ndarray, d_sim: np.ndarray) -> list[float]:
        """Eq. 25 per axis, and the same for the norms (|d_ref| - |d_sim|) / |d_ref|."""
        with np.errstate(divide="ignore", invalid="ignore"):
            axes = np.abs((d_ref - d_sim) / d_ref) * 100.0
            norm = abs(np.linalg.norm(d_ref) - np.linalg.norm(d_sim)) / np.linalg.norm(d_ref) * 100.0
        # no measured shift along an axis: the percentage is undefined (null in JSON)
        return [float(v) if np.isfinite(v) else None for v in [*axes, norm]]

    def as_dict(self) -> dict:
        return {
            "index_pre": self.index_pre,
            "p_pre": self.p_pre.tolist(),
            "p_intra": self.p_intra.tolist(),
            "p_sim": self.p_sim.tolist(),
            "d_mri": self.d_mri.tolist(),
            "d_mri_bar": self.d_mri_bar.tolist(),
            "d_sim": self.d_sim.tolist(),
            "error_percent_vs_d_mri": self.error_percent(self.d_mri, self.d_sim),
            "error_percent_vs_d_mri_bar": self.error_percent(self.d_mri_bar, self.d_sim),
        }


def landmark(
    name: str,
    pre: np.ndarray,
    intra: np.ndarray,
    sim: np.ndarray,
    direction,
    radius: float,
    depth: float,
    search: float,
) -> Landmark:
    d = _unit(direction)
    if pre.shape != sim.shape:
        raise InputError(f"SIM has {len(sim)} vertices, PRE {len(pre)}: SIM must be PRE moved by the simulation")
    a = int(np.argmax(pre @ d))
    p_pre, p_sim = pre[a], sim[a]
    rel = intra - p_sim
    lateral = np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)
    near = np.flatnonzero(lateral < search)
    if len(near) == 0:
        raise InputError(f"node {name}: no INTRA vertex within {search:g} of the simulated position; raise search")
    i = near[np.argmax(intra[near] @ d)]
    p_intra = intra[i]
    c_pre = pre[region(pre, p_pre, d, radius, depth)].mean(axis=0)
    c_intra = intra[region(intra, p_intra, d, radius, depth)].mean(axis=0)
    return Landmark(name, a, p_pre, p_intra, p_sim, p_intra - p_pre, c_intra - c_pre, p_sim - p_pre)


def surface_error(intra: np.ndarray, sim: np.ndarray, height_axis: int, roi, spacing: float, top_depth: float) -> dict:
    """SIM - INTRA heights on a grid over roi = ((a0, a1), (b0, b1)) of the other two axes.
    A closed surface passes over each grid point twice; only its upper part counts: the
    vertices within ``top_depth`` of the highest vertex in the ROI (the exposed cortex a camera
    or the paper's griddata of a relatively flat region sees)."""
    from scipy.interpolate import griddata

    a, b = [k for k in range(3) if k != height_axis]
    (a0, a1), (b0, b1) = roi
    ga = np.arange(a0, a1 + 0.5 * spacing, spacing)
    gb = np.arange(b0, b1 + 0.5 * spacing, spacing)
    A, B = np.meshgrid(ga, gb, indexing="ij")

    def heights(points):
        pad = 2 * spacing
        keep = (
            (points[:, a] >= a0 - pad)
            & (points[:, a] <= a1 + pad)
            & (points[:, b] >= b0 - pad)
            & (points[:, b] <= b1 + pad)
        )
        if keep.sum() < 3:
            raise InputError("fewer than three surface vertices in the ROI: check its bounds and units")
        keep &= points[:, height_axis] >= points[keep][:, height_axis].max() - top_depth
        return griddata(points[keep][:, [a, b]], points[keep][:, height_axis], (A, B), method="linear")

    diff = heights(sim) - heights(intra)
    values = diff[np.isfinite(diff)]
    if values.size == 0:
        raise InputError("the ROI lies outside both surfaces")
    return {
        "grid_points": int(values.size),
        "max": float(values.max()),
        "min": float(values.min()),
        "mean": float(values.mean()),
        "median": float(np.median(values)),
        "mae": float(np.abs(values).mean()),
        "grid_a": ga.tolist(),
        "grid_b": gb.tolist(),
        "error": np.where(np.isfinite(diff), diff, np.nan).tolist(),
    }


def compare(
    pre,
    intra,
    sim,
    up,
    second,
    radius: float,
    depth: float,
    search: float,
    roi=None,
    spacing: float | None = None,
    top_depth: float = 0.02,
) -> dict:
    """All of the paper's measures as one dictionary (lengths in the surfaces' units)."""
    out = {
        "A": landmark("A", pre, intra, sim, up, radius, depth, search).as_dict(),
        "B": landmark("B", pre, intra, sim, second, radius, depth, search).as_dict(),
    }
    if roi is not None:
        height_axis = int(np.argmax(np.abs(_unit(up))))
        out["surface_error"] = surface_error(intra, sim, height_axis, roi, spacing, top_depth)
        out["surface_error"]["height_axis"] = "xyz"[height_axis]
    return out
