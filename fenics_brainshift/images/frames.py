"""The two frames of the Slicer world, and Slicer's markups files.

3D Slicer's scene, NIfTI and this project's meshes use RAS (x to the right, y anterior, z
superior); ITK, DICOM, Slicer's markups files (since Slicer 4.11) and its transform files use
LPS (left, posterior, superior). The two differ by the sign of x and y, nothing else.

Markups (.mrk.json, Slicer's point lists) are read with the json module; their
``coordinateSystem`` says the frame of the positions. Points go out in LPS, as Slicer writes
them, so a point read from one file and written to another comes back where it was.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

from .. import json_text
from ..errors import InputError

log = logging.getLogger(__name__)

LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0])  # its own inverse
MARKUPS_SCHEMA = (
    "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/"
    "Resources/Schema/markups-schema-v1.0.3.json#"
)


def lps_to_ras(points: np.ndarray) -> np.ndarray:
    """Points (n, 3) from LPS to RAS (x and y negated)."""
    return np.asarray(points, dtype=float) @ LPS_TO_RAS


def ras_to_lps(points: np.ndarray) -> np.ndarray:
    """Points (n, 3) from RAS to LPS: the same sign flip as lps_to_ras."""
    return lps_to_ras(points)


# several points all within this many mm of the origin: metres written where mm belong (a
# brain's landmarks in metres are all within 0.2 "mm" of it)
METRES_LOOK = 1.0


def read_markups(path: str | Path, what: str = "markups") -> tuple[list[str], np.ndarray]:
    """(labels, RAS points in mm, shape (n, 3)) of every control point in a .mrk.json file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what}: no file '{path}'")
    try:
        document = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{what}: '{path.name}' is not a Slicer markups file (JSON: {exc})") from None
    markups = document.get("markups") if isinstance(document, dict) else None
    if not isinstance(markups, list) or not markups:
        raise InputError(
            f"{what}: '{path.name}' has no \"markups\" list; save a point list from 3D Slicer "
            f"(Markups module) as .mrk.json"
        )
    labels, points, unplaced = [], [], 0
    for m, markup in enumerate(markups):
        if not isinstance(markup, dict):
            raise InputError(
                f"{what}: '{path.name}': markups entry {m} is not an object (got {markup!r}); save "
                f"the point list from 3D Slicer (Markups module) as .mrk.json"
            )
        frame = str(markup.get("coordinateSystem", "LPS")).upper()
        if frame not in ("LPS", "RAS"):
            raise InputError(f"{what}: '{path.name}': coordinateSystem '{frame}' is neither LPS nor RAS")
        units = str(markup.get("coordinateUnits", "mm"))
        if units != "mm":
            raise InputError(f"{what}: '{path.name}': coordinateUnits '{units}'; millimetres are expected")
        points_in_file = markup.get("controlPoints") or []
        if not isinstance(points_in_file, list):
            raise InputError(f"{what}: '{path.name}': \"controlPoints\" is not a list")
        for n, point in enumerate(points_in_file):
            if isinstance(point, dict) and point.get("positionStatus") in ("undefined", "preview", "missing"):
                unplaced += 1  # listed, never placed or skipped ("position": ""): Slicer leaves it out
                continue
            position = point.get("position") if isinstance(point, dict) else None
            if (
                not isinstance(position, list)
                or len(position) != 3
                or not all(
                    isinstance(c, float) or (isinstance(c, int) and not isinstance(c, bool) and abs(c) < 1e300)
                    for c in position
                )
            ):  # (an int past float range: OverflowError)
                raise InputError(
                    f"{what}: '{path.name}': control point {n + 1} has no position of 3 numbers (got {position!r})"
                )
            xyz = np.asarray(position, dtype=float)
            if not np.isfinite(xyz).all():
                raise InputError(
                    f"{what}: '{path.name}': control point {n + 1} ('{point.get('label', '')}') has a "
                    f"position that is not finite ({position}); delete or place it again in Slicer"
                )
            points.append(lps_to_ras(xyz) if frame == "LPS" else xyz)
            labels.append(str(point.get("label") or f"P-{len(labels) + 1}"))
    if unplaced:
        log.warning(
            "%s: '%s': %d control point(s) never placed in Slicer (positionStatus undefined, preview or "
            "missing) left out",
            what,
            path.name,
            unplaced,
        )
    if not points:
        raise InputError(
            f"{what}: '{path.name}' holds no control points"
            + (f" that were placed ({unplaced} never placed)" if unplaced else "")
        )
    points = np.array(points)
    if len(points) > 1 and np.abs(points).max() < METRES_LOOK:
        raise InputError(
            f"{what}: '{path.name}': every position is within {METRES_LOOK:g} mm of the origin "
            f"(largest {np.abs(points).max():.3g}): positions in metres? Slicer markups are in mm"
        )
    return labels, points


def write_markups(path: str | Path, labels: list[str], ras_mm: np.ndarray) -> Path:
    """A Slicer point list (.mrk.json, positions in LPS mm) of RAS points, written atomically."""
    path = Path(path)
    points = [
        {"id": str(n + 1), "label": label, "position": [float(c) for c in ras_to_lps(p)], "positionStatus": "defined"}
        for n, (label, p) in enumerate(zip(labels, np.asarray(ras_mm)))
    ]
    document = {
        "@schema": MARKUPS_SCHEMA,
        "markups": [{"type": "Fiducial", "coordinateSystem": "LPS", "coordinateUnits": "mm", "controlPoints": points}],
    }
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json_text.dumps(document) + "\n")
    os.replace(tmp, path)
    return path
