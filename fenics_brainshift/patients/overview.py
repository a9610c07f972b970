"""overview.png of a prepared patient: the T1 in three planes through the tumour's centre (the
brain's when there is no tumour), with the outline of the brain found and of each carried label
(tumour, supports), a 50 mm scale bar, resampled onto an axis-aligned 1 mm grid (a T1 scanned
oblique is shown in the head's RAS frame). Written also when prepare refuses the registration:
the picture of what was found is how to judge it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import SimpleITK as sitk

COLOURS = {"brain": "#ffd23f", "tumour": "#ff3b3b", "brain_stem": "#3fa7ff", "occipital_pole": "#5fdc5f"}


def write_overview(path: Path, t1: sitk.Image, labels: np.ndarray, names: dict[int, str], title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    label_image = sitk.GetImageFromArray(labels)
    label_image.CopyInformation(t1)
    brain = labels > 0
    corners = np.argwhere(brain)
    lo, hi = corners.min(axis=0)[::-1], corners.max(axis=0)[::-1]  # i, j, k
    box = np.array(
        [
            t1.TransformIndexToPhysicalPoint([int(a), int(b), int(c)])
            for a in (lo[0], hi[0])
            for b in (lo[1], hi[1])
            for c in (lo[2], hi[2])
        ]
    )
    origin = box.min(axis=0) - 10.0  # LPS mm, an axis-aligned grid around the brain
    size = [int(v) for v in np.ceil(box.max(axis=0) + 10.0 - origin)]
    grid = dict(
        size=size, outputOrigin=origin.tolist(), outputSpacing=[1.0] * 3, outputDirection=np.eye(3).ravel().tolist()
    )
    image = sitk.GetArrayFromImage(sitk.Resample(t1, transform=sitk.Transform(), interpolator=sitk.sitkLinear, **grid))
    moved = sitk.GetArrayFromImage(
        sitk.Resample(label_image, transform=sitk.Transform(), interpolator=sitk.sitkNearestNeighbor, **grid)
    )
    focus = [v for v, label in names.items() if label == "tumour" and np.any(moved == v)]
    # [k (S), j (P), i (L)]: through the tumour, so that every plane shows it
    centre = np.argwhere(moved == focus[0] if focus else moved > 0).mean(axis=0).astype(int)
    lo_v, hi_v = np.percentile(image[moved > 0], [1, 99]) if np.any(moved > 0) else (image.min(), image.max())
    # the arrays are [k, j, i] = [S, P, L] from the grid's LPS corner; in the radiological view
    # (the patient's right on the picture's left), anterior and superior up, anterior to the left
    views = [
        ("axial", lambda a: a[centre[0]], ("R", "L"), ("P", "A")),
        ("coronal", lambda a: a[::-1, centre[1], :], ("R", "L"), ("I", "S")),
        ("sagittal", lambda a: a[::-1, :, centre[2]], ("A", "P"), ("I", "S")),
    ]
    figure, axes = plt.subplots(1, 3, figsize=(13, 5))
    for ax, (name, cut, (left, right), (bottom, top)) in zip(axes, views):
        ax.imshow(cut(image), cmap="gray", vmin=lo_v, vmax=hi_v, origin="upper")
        for value, label in names.items():
            mask = cut(moved) == value if label != "brain" else cut(moved) > 0
            if mask.any():
                ax.contour(mask.astype(float), levels=[0.5], colors=COLOURS.get(label, "white"), linewidths=1.2)
        _scale_bar(ax, cut(image).shape)
        ax.set_title(name, fontsize=13)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_xlabel(f"{left} ← → {right}", fontsize=11)
        ax.set_ylabel(f"{bottom} ← → {top}", fontsize=11)
    handles = [plt.Line2D([], [], color=COLOURS.get(label, "white"), lw=2, label=label) for label in names.values()]
    figure.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=11, frameon=False)
    figure.suptitle(title, fontsize=13)
    figure.tight_layout(rect=(0, 0.07, 1, 0.95))
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return Path(path)


SCALE_MM = 50.0


def _scale_bar(ax, shape) -> None:
    """A SCALE_MM bar in the lower right (the grid is 1 mm)."""
    rows, cols = shape
    y, x1 = rows - 0.06 * rows, cols - 0.05 * cols
    ax.plot([x1 - SCALE_MM, x1], [y, y], color="white", lw=3, solid_capstyle="butt")
    ax.text(
        x1 - SCALE_MM / 2, y - 0.02 * rows, f"{SCALE_MM:g} mm", color="white", ha="center", va="bottom", fontsize=10
    )
