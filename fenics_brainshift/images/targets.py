"""What was measured in the operating room, as points in the scene's frame (RAS, m).

- point to point: the intra-operative positions of points whose pre-operative positions are
  known: ``--target intra.mrk.json --pre pre.mrk.json`` (matched by label), a CSV with
  columns ``x_pre, y_pre, z_pre, x, y, z`` (and optionally ``label``), or an MNI tag file of
  landmark pairs (``.tag``, Volumes = 2: the pre-operative volume's point first, then the
  intra-operative one's, as the RESECT ultrasound database ships MRI-to-ultrasound pairs);
- point to surface: positions on the exposed cortex with no correspondence (a tracked pointer,
  a laser scan): ``--target points.mrk.json`` or a CSV with ``x, y, z``, or a surface file
  (.vtk, .stl, .ply, ...: its vertices); the residual is the signed distance to the predicted
  surface of the brain.

Millimetres in every file (what Slicer and trackers write). Frames: a markups file declares its
own (coordinateSystem), a surface file in its header (SPACE=LPS, as Slicer writes it); a tag
file is in MINC's world coordinates (RAS); a CSV file and an untagged surface are in
``--frame`` (default RAS). Everything is turned to RAS.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import formats
from ..errors import InputError
from .frames import read_markups

MAX_SURFACE_POINTS = 2000  # a scanned surface is thinned to about this many points
# a point's measurement noise (mm per coordinate): a tracked pointer's is 0.5-2 mm, an ultrasound
# landmark's 1-3 mm; outside this range the number is a slip of unit or of typing
NOISE_MM = (0.01, 50.0)


def check_noise(noise_mm: float, flag: str = "--noise") -> None:
    """Refuse a measurement noise outside NOISE_MM (InputError naming the flag)."""
    low, high = NOISE_MM
    if not low <= noise_mm <= high:
        raise InputError(
            f"{flag}: {noise_mm:.10g} mm; a point's measurement noise is {low:g}-{high:g} mm per coordinate "
            f"(a tracked pointer about 1 mm; in mm, not m)"
        )


@dataclass
class Target:
    """Measured intra-operative points (m, RAS) with their labels: point to point with the
    same points before the shift (``pre``), else point to the predicted surface; both at once
    where ``pre`` has rows of NaN (those points to the surface: a pointer's touches on the
    cortex beside landmark pairs, as the live service takes them)."""

    measured: np.ndarray  # (n, 3) intra-operative positions, m
    pre: np.ndarray | None  # (n, 3) the same points before (point to point), or None (to the surface)
    labels: list[str]

    @property
    def pairs(self) -> np.ndarray:
        """The indices of the points fitted point to point."""
        if self.pre is None:
            return np.zeros(0, dtype=np.int64)
        return np.flatnonzero(np.isfinite(self.pre).all(axis=1))

    @property
    def kind(self) -> str:
        pairs = len(self.pairs)
        if pairs == len(self.measured):
            return "point-to-point"
        return "point-to-surface" if not pairs else "point-to-point and point-to-surface"

    @property
    def places(self) -> np.ndarray:
        """(n, 3) where each point is on the pre-operative brain, near enough: a pair's
        pre-operative point, a point to the surface's measured one (it has no other)."""
        if self.pre is None:
            return self.measured
        return np.where(np.isfinite(self.pre).all(axis=1)[:, None], self.pre, self.measured)

    def subset(self, keep) -> Target:
        """The same kind of target over these points."""
        keep = np.asarray(keep, dtype=np.int64)
        return Target(self.measured[keep], None if self.pre is None else self.pre[keep], [self.labels[i] for i in keep])


def read_target(target: str | Path, pre: str | Path | None = None, frame: str | None = None) -> Target:
    """The measurements in RAS m; ``frame`` (RAS / LPS, None: RAS) is that of a CSV file and of
    a surface file whose header does not declare one; a markups file declares its own."""
    target = Path(target)
    if not target.is_file():
        raise InputError(f"--target: no file '{target}'")
    name = target.name.lower()
    if name.endswith(".mrk.json") and frame is not None:
        raise InputError("--frame is for a CSV or surface target: a markups file declares its own coordinateSystem")
    if name.endswith(".mrk.json"):
        labels, points = read_markups(target, "--target")
        if pre is None:
            return Target(points * 1e-3, None, labels)
        pre_labels, pre_points = read_markups(pre, "--pre")
        for option, names, path in (("--target", labels, target), ("--pre", pre_labels, Path(pre))):
            twice = sorted({label for label in names if names.count(label) > 1})
            if twice:  # matching by label would pair one of them at random
                raise InputError(
                    f"{option}: '{path.name}': the label(s) {', '.join(twice[:5])} name more than one "
                    f"point; give each point its own label (points are matched by label)"
                )
        where = {label: i for i, label in enumerate(pre_labels)}
        missing = [label for label in labels if label not in where]
        if missing:
            raise InputError(
                f"--target: points {', '.join(missing[:5])} have no namesake in --pre '{Path(pre).name}'; "
                f"label each intra-operative point as its pre-operative one"
            )
        return Target(points * 1e-3, pre_points[[where[label] for label in labels]] * 1e-3, labels)
    if pre is not None:
        raise InputError(
            "--pre goes with a .mrk.json --target (points matched by label); a CSV or .tag target "
            "carries the pre-operative points itself"
        )
    if name.endswith(".tag"):
        if frame is not None:
            raise InputError("--frame is for a CSV or surface target: a .tag file is in MINC's world frame (RAS)")
        return _read_tag(target)
    if name.endswith(".csv"):
        return _read_csv(target, frame)
    if formats.is_surface(target):
        from ..surfaces.files import read_surface

        points, _ = read_surface(target, 1e-3, frame)
        _check_millimetres(points * 1e3, target)
        points = np.unique(points, axis=0)
        if len(points) > MAX_SURFACE_POINTS:
            points = points[np.linspace(0, len(points) - 1, MAX_SURFACE_POINTS).astype(int)]
        return Target(points, None, [f"s{i}" for i in range(len(points))])
    raise InputError(
        f"--target: '{target.name}': use a Slicer point list (.mrk.json), a CSV (x, y, z in mm), an "
        f"MNI .tag of landmark pairs or a surface ({', '.join(formats.SURFACE_SUFFIXES)})"
    )


def read_surface_points(path: str | Path, frame: str | None, option: str) -> Target:
    """Points to fit to a surface alone (``option``: the flag named in messages, e.g.
    --cavity): a point list, a CSV of positions or a surface file, never pairs."""
    try:
        target = read_target(path, None, frame)
    except InputError as exc:
        raise InputError(str(exc).replace("--target", option, 1)) from None
    if target.pre is not None:
        raise InputError(
            f"{option}: '{Path(path).name}' holds point pairs; give positions alone (they are fitted to the surface)"
        )
    return target


def with_surface_points(target: Target, more: Target, name: str) -> Target:
    """The target with ``more`` points fitted to the surface (labelled NAME-1, NAME-2, ...)."""
    n = len(more.measured)
    labels = list(target.labels) + [f"{name}-{i + 1}" for i in range(n)]
    measured = np.concatenate([target.measured, more.measured])
    if target.pre is None:
        return Target(measured, None, labels)
    return Target(measured, np.concatenate([target.pre, np.full((n, 3), np.nan)]), labels)


def _read_csv(path: Path, frame: str | None) -> Target:
    try:  # utf-8-sig: a byte-order mark, as Excel writes one, is not part of the first column's name
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f, skipinitialspace=True)  # ("x, y, z" as the docs write it)
            if reader.fieldnames:
                reader.fieldnames = [name.strip() for name in reader.fieldnames]
            rows = list(reader)
    except UnicodeDecodeError as exc:  # (a Latin-1 label, or not text at all)
        raise InputError(
            f"--target: '{path.name}' is not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at "
            f'{exc.start}): save it as UTF-8 (a spreadsheet\'s "CSV UTF-8"), x, y, z in mm under a '
            f"header line; or give a Slicer .mrk.json or a surface"
        ) from None
    except csv.Error as exc:
        raise InputError(
            f"--target: '{path.name}' is not a CSV file ({exc}): give x, y, z in mm (a header line, "
            f"then a row per point), a Slicer .mrk.json or a surface"
        ) from None
    if not rows:
        raise InputError(f"--target: '{path.name}' has no rows under a header line")
    columns = set(rows[0])
    pre_columns = {"x_pre", "y_pre", "z_pre"} & columns
    if pre_columns and pre_columns != {"x_pre", "y_pre", "z_pre"}:
        raise InputError(
            f"--target: '{path.name}' has {', '.join(sorted(pre_columns))} but not all of x_pre, y_pre, "
            f"z_pre: give all three (point to point) or none (point to surface)"
        )
    if not {"x", "y", "z"} <= columns:
        raise InputError(
            f"--target: '{path.name}' needs columns x, y, z (mm; and x_pre, y_pre, z_pre for point "
            f"to point); it has {', '.join(sorted(columns))}"
        )
    keys = list("xyz") + ([f"{k}_pre" for k in "xyz"] if {"x_pre", "y_pre", "z_pre"} <= columns else [])
    values = np.zeros((len(rows), len(keys)))
    for i, row in enumerate(rows):
        line = i + 2  # the header is line 1
        if None in row:  # more values than the header names
            raise InputError(f"--target: '{path.name}' line {line} has more values than the header's columns")
        for j, key in enumerate(keys):
            text = row[key]
            try:
                values[i, j] = float(text)
            except (TypeError, ValueError):
                what = "is missing" if text is None or not text.strip() else f"is not a number ({text!r})"
                raise InputError(f"--target: '{path.name}' line {line}: {key} {what}") from None
            if not np.isfinite(values[i, j]):
                raise InputError(f"--target: '{path.name}' line {line}: {key} = {text} is not a finite number")
    if frame == "LPS":  # to RAS: x and y negated
        values *= np.tile([-1.0, -1.0, 1.0], len(keys) // 3)
    _check_millimetres(values, path)
    measured = values[:, :3]
    pre = values[:, 3:] if len(keys) == 6 else None
    labels = [r.get("label") or f"p{i + 1}" for i, r in enumerate(rows)]
    return Target(measured * 1e-3, None if pre is None else pre * 1e-3, labels)


def _read_tag(path: Path) -> Target:
    """An MNI tag file of landmark pairs: a header line "MNI Tag Point File", "Volumes = 2;",
    then after "Points =" one line per pair: x1 y1 z1 x2 y2 z2 (mm), optionally a weight, a
    structure id, a patient id and a quoted label; the last ends with ";"."""
    text = path.read_text(errors="replace")
    if not text.lstrip().startswith("MNI Tag Point File"):
        raise InputError(
            f"--target: '{path.name}' is not an MNI tag file (its first line must be 'MNI Tag Point File')"
        )
    head, sep, body = text.partition("Points =")
    volumes = [line.split("=", 1)[1].strip(" ;") for line in head.splitlines() if line.strip().startswith("Volumes")]
    if not sep or volumes != ["2"]:
        raise InputError(
            f"--target: '{path.name}' must hold landmark pairs (Volumes = 2; then Points =), it has "
            f"{'Volumes = ' + volumes[0] if volumes else 'no Volumes line'}"
        )
    pre, measured, labels = [], [], []
    for line in body.replace(";", "\n").splitlines():
        label = line.split('"')[1] if line.count('"') >= 2 else None
        fields = line.split('"')[0].split()
        if not fields:
            continue
        try:
            values = [float(v) for v in fields[:6]]
        except ValueError:
            values = []
        if len(values) < 6 or not np.all(np.isfinite(values)):
            raise InputError(
                f"--target: '{path.name}': point {len(pre) + 1} is not six finite numbers "
                f"(x1 y1 z1 x2 y2 z2 mm): {line.strip()[:60]!r}"
            )
        pre.append(values[:3])
        measured.append(values[3:6])
        labels.append(label or str(len(pre)))
    if not pre:
        raise InputError(f"--target: '{path.name}' holds no points after 'Points ='")
    _check_millimetres(np.hstack([pre, measured]), path)
    if len(set(labels)) != len(labels):
        labels = [f"{label}#{i + 1}" for i, label in enumerate(labels)]
    return Target(np.array(measured) * 1e-3, np.array(pre) * 1e-3, labels)


def _check_millimetres(values_mm: np.ndarray, path: Path) -> None:
    """Several points all within METRES_LOOK mm of the origin: metres where mm belong."""
    from .frames import METRES_LOOK

    if len(values_mm) > 1 and np.abs(values_mm).max() < METRES_LOOK:
        raise InputError(
            f"--target: '{path.name}': every position is within {METRES_LOOK:g} mm of the origin "
            f"(largest {np.abs(values_mm).max():.3g}): positions in metres? give millimetres"
        )
