"""update.png: what an update did, for the person at the navigation screen. Three planes of the
pre-operative image through the measured points (axial, coronal, sagittal, resampled on the
head's RAS axes, radiological view), the updated shift's size in colour with its in-plane
direction as arrows and the uncertainty as contour lines, the measured points near each plane;
and beside them every point's residual before (the scene's prediction) and after the update."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

HALF_WIDTH_MM = 60.0  # each plane shows this far around the measured points' centre
STEP_MM = 1.0
NEAR_PLANE_MM = 5.0  # a measured point this close to a plane is drawn on it
SPREAD_LINES_MM = (0.5, 1.0, 2.0)


# (name, the picture's rightward and upward directions in RAS, the plane's normal axis, labels):
# radiological, the patient's right on the picture's left; superior and anterior up
PLANES = [
    ("axial", (-1, 0, 0), (0, 1, 0), 2, ("R", "L"), ("P", "A")),
    ("coronal", (-1, 0, 0), (0, 0, 1), 1, ("R", "L"), ("I", "S")),
    ("sagittal", (0, -1, 0), (0, 0, 1), 0, ("A", "P"), ("I", "S")),
]
ARROW_STEP = 10  # pixels (mm) between arrows


@dataclass
class _Plane:
    """One plane through the points' centre, sampled on its pixels (row 0 at the top)."""

    name: str
    right: np.ndarray  # RAS direction of the picture's rightward
    up: np.ndarray  # ... and upward
    normal: int  # the RAS axis across the plane
    labels: tuple  # ((left, right), (bottom, top))
    gray: np.ndarray  # the image
    inside: np.ndarray  # (pixels,) bool: in the atlas's mesh
    shift: np.ndarray  # (pixels, 3) mm, the updated displacement
    spread: np.ndarray  # the uncertainty (mm), NaN outside


def write_update_picture(path: Path, image, atlas, target, result) -> Path:
    """image: images.volumes.Volume (RAS mm); atlas: store.Atlas; target: images.targets.Target (m);
    result: update.UpdateResult."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points_mm = target.places * 1e3
    centre = points_mm.mean(axis=0)
    planes = _sampled_planes(image, atlas, result, centre)
    # one colour scale and one arrow scale for the three planes (each its own misled)
    sizes = [np.linalg.norm(plane.shift[plane.inside], axis=1) for plane in planes]
    top_size = max([1.0] + [float(v.max()) for v in sizes if len(v)])
    figure, axes = plt.subplots(1, 4, figsize=(19, 5.2), gridspec_kw={"width_ratios": [1, 1, 1, 1.15]})
    shown = None
    for ax, plane in zip(axes, planes):
        shown = _draw_plane(ax, plane, top_size, points_mm, centre)
    if shown is not None:
        bar = figure.colorbar(shown, ax=axes[2], fraction=0.046, pad=0.03)
        bar.set_label("updated shift (mm); cyan lines: uncertainty (mm)")
    _draw_residuals(axes[3], target, result)
    figure.suptitle(
        f"update from {len(result.residual)} points: green circles, the measured points within "
        f"{NEAR_PLANE_MM:g} mm of a plane",
        fontsize=12,
    )
    figure.subplots_adjust(wspace=0.45)
    figure.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(figure)
    return Path(path)


def _sampled_planes(image, atlas, result, centre: np.ndarray) -> list[_Plane]:
    """The image, the updated shift and its spread on the three planes through centre (mm)."""
    from scipy.ndimage import map_coordinates

    from .prepared import locator as prepared_locator

    n = int(round(2 * HALF_WIDTH_MM / STEP_MM)) + 1
    offsets = (np.arange(n) - (n - 1) / 2) * STEP_MM
    locator = prepared_locator(atlas)  # (made once per atlas)
    out = []
    for name, right, up, normal, left_right, bottom_top in PLANES:
        right, up = np.array(right, float), np.array(up, float)
        col, row = np.meshgrid(offsets, offsets[::-1], indexing="xy")  # row 0 at the top
        ras = centre + col.reshape(-1, 1) * right + row.reshape(-1, 1) * up
        gray = map_coordinates(
            np.asarray(image.data, dtype=np.float32), image.ras_to_index(ras).T, order=1, cval=0.0
        ).reshape(col.shape)
        index, weight, outside = locator.weights(ras * 1e-3)
        inside = outside <= 0
        shift = np.einsum("nj,njd->nd", weight, result.displacement[index]) * 1e3
        spread = np.where(inside, np.einsum("nj,nj->n", weight, result.spread[index]) * 1e3, np.nan)
        out.append(
            _Plane(name, right, up, normal, (left_right, bottom_top), gray, inside, shift, spread.reshape(col.shape))
        )
    return out


def _draw_plane(ax, plane: _Plane, top_size: float, points_mm: np.ndarray, centre: np.ndarray):
    """The image, the shift's size in colour and its in-plane direction as arrows (the largest
    0.9 of their spacing), the uncertainty's contour lines, the measured points near the plane
    and a 50 mm bar; returns the colour image (for the colour bar)."""
    shape = plane.gray.shape
    size = np.where(plane.inside, np.linalg.norm(plane.shift, axis=1), np.nan).reshape(shape)
    lo, hi = np.percentile(plane.gray[plane.gray > 0], [1, 99]) if np.any(plane.gray > 0) else (0, 1)
    extent = (0, shape[1], shape[0], 0)
    ax.imshow(plane.gray, cmap="gray", vmin=lo, vmax=hi, extent=extent)
    shown = ax.imshow(size, cmap="inferno", alpha=0.55, vmin=0, vmax=top_size, extent=extent)
    if np.any(np.isfinite(plane.spread)):
        lines = ax.contour(
            np.arange(shape[1]) + 0.5,
            np.arange(shape[0]) + 0.5,
            plane.spread,
            levels=list(SPREAD_LINES_MM),
            colors="cyan",
            linewidths=0.8,
        )
        ax.clabel(lines, fmt="%g mm", fontsize=7)
    rows, cols = np.mgrid[ARROW_STEP // 2 : shape[0] : ARROW_STEP, ARROW_STEP // 2 : shape[1] : ARROW_STEP]
    flat = rows.ravel() * shape[1] + cols.ravel()
    keep = plane.inside[flat]
    if keep.any():  # (quiver's arrows are drawn in screen directions: up is up whatever the axis's sense)
        ax.quiver(
            cols.ravel()[keep] + 0.5,
            rows.ravel()[keep] + 0.5,
            plane.shift[flat[keep]] @ plane.right,
            plane.shift[flat[keep]] @ plane.up,
            color="white",
            width=0.004,
            alpha=0.9,
            angles="uv",
            scale_units="xy",
            scale=top_size / (0.9 * ARROW_STEP),
        )
    near = np.abs((points_mm - centre)[:, plane.normal]) < NEAR_PLANE_MM
    for p in points_mm[near]:
        ax.plot(
            (p - centre) @ plane.right / STEP_MM + shape[1] / 2,
            shape[0] / 2 - (p - centre) @ plane.up / STEP_MM,
            "o",
            ms=6,
            mfc="none",
            mec="lime",
            mew=1.5,
        )
    ax.plot([shape[1] - 8 - 50 / STEP_MM, shape[1] - 8], [shape[0] - 8] * 2, color="white", lw=3)
    ax.text(shape[1] - 8 - 25 / STEP_MM, shape[0] - 11, "50 mm", color="white", ha="center", fontsize=9)
    (left, right), (bottom, top) = plane.labels
    ax.set_title(f"{plane.name} through the points", fontsize=12)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_xlabel(f"{left} ← → {right}")
    ax.set_ylabel(f"{bottom} ← → {top}")
    return shown


def _draw_residuals(ax, target, result) -> None:
    """Every point's residual before (the scene's prediction) and after the update, mm."""
    order = np.arange(len(result.residual))
    ax.bar(order - 0.2, result.prior_residual * 1e3, width=0.4, color="#bbbbbb", label="scene's prediction")
    ax.bar(order + 0.2, result.residual * 1e3, width=0.4, color="#d9480f", label="updated")
    for i in result.outliers:
        ax.annotate("set aside", (i + 0.2, result.residual[i] * 1e3), fontsize=7, rotation=90, va="bottom")
    ax.set_xticks(order)
    ax.set_xticklabels(target.labels, rotation=90, fontsize=7)
    ax.set_ylabel("distance from the measured point (mm)")
    ax.set_title("each point: before and after", fontsize=12)
    ax.legend(fontsize=9, frameon=False)
