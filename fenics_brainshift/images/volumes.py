"""Image volumes as 3D Slicer writes them: NIfTI (nibabel) and NRRD (pynrrd), one view of both.

A Volume is the voxel array indexed [i, j, k] and the affine that takes the index (i, j, k)
to RAS millimetres (right, anterior, superior: NIfTI's and Slicer's scene frame). NRRD files
say their frame in the ``space`` field; an LPS file ("left-posterior-superior", what ITK and
Slicer write) is turned to RAS by negating the first two rows. ``write_like`` writes a new
array on the grid of a volume read before, with that file's own header (nibabel's or
pynrrd's), through a temporary file and a rename: never half a file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..logs import get_logger
from .frames import LPS_TO_RAS

log = get_logger("images")

NIFTI_SUFFIXES = (".nii", ".nii.gz")
NRRD_SUFFIXES = (".nrrd", ".nhdr")  # .seg.nrrd included
VOLUME_HELP = "use a NIfTI (.nii, .nii.gz) or NRRD (.nrrd, .seg.nrrd) volume"
MAX_VOXELS = 500e6  # a whole head at 0.4 mm is 100 million

# the NRRD ``space`` values and the sign flips that take them to RAS
_NRRD_SPACES = {
    "right-anterior-superior": np.eye(3),
    "ras": np.eye(3),
    "left-posterior-superior": LPS_TO_RAS,
    "lps": LPS_TO_RAS,
}


def is_volume(path: str | Path) -> bool:
    """Whether a file name is a volume this package reads (NIfTI or NRRD)."""
    return str(path).lower().endswith(NIFTI_SUFFIXES + NRRD_SUFFIXES)


@dataclass
class Volume:
    """A NIfTI or NRRD volume as one RAS view: its voxels [i, j, k], the affine to RAS mm, the
    reader's header (to write a volume like it) and a Slicer segmentation's segments."""

    path: Path
    data: np.ndarray  # [i, j, k] (3D); a label or intensity per voxel
    affine: np.ndarray  # 4x4: (i, j, k, 1) -> RAS mm
    header: object = field(repr=False, default=None)  # the reader's header, for write_like
    segments: dict[int, str] = field(default_factory=dict)  # .seg.nrrd: label value -> segment name
    # a .seg.nrrd whose segments overlap, as Slicer writes it: [layer, i, j, k] (data is layer 0),
    # and each segment's (layer, label value)
    layers: np.ndarray | None = field(repr=False, default=None)
    segment_layers: dict[str, tuple[int, int]] = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return "nifti" if str(self.path).lower().endswith(NIFTI_SUFFIXES) else "nrrd"

    @property
    def spacing(self) -> np.ndarray:
        """The voxel size along i, j, k (mm)."""
        return np.linalg.norm(self.affine[:3, :3], axis=0)

    def index_to_ras(self, ijk: np.ndarray) -> np.ndarray:
        return ijk @ self.affine[:3, :3].T + self.affine[:3, 3]

    def ras_to_index(self, ras: np.ndarray) -> np.ndarray:
        inverse = np.linalg.inv(self.affine)
        return ras @ inverse[:3, :3].T + inverse[:3, 3]


def read_volume(path: str | Path, what: str = "--image", layered: bool = False) -> Volume:
    """A 3D NIfTI or NRRD volume (a 4D file with one volume is squeezed); InputError names
    ``what`` for a missing, unreadable or non-3D file. ``layered``: a Slicer segmentation
    whose segments overlap (a 4D .seg.nrrd of layers) is read too, for label_mask."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what}: no file '{path}'")
    if not is_volume(path):
        raise InputError(f"{what}: '{path.name}' is not a volume; {VOLUME_HELP}")
    try:
        volume = _read_nifti(path, what) if path.name.lower().endswith(NIFTI_SUFFIXES) else _read_nrrd(path, what)
    except InputError:
        raise
    except Exception as exc:  # a damaged file: the reader's own words
        raise InputError(f"{what}: '{path.name}' could not be read ({exc})") from None
    data = volume.data
    while data.ndim > 3 and data.shape[-1] == 1:
        data = data[..., 0]
    if volume.layers is not None and not layered:
        raise InputError(
            f"{what}: '{path.name}' is a segmentation with overlapping segments ({data.shape[0]} "
            f"layers); export the segments needed as a labelmap in Slicer"
        )
    if volume.layers is not None:
        data = data[0]
    if data.ndim != 3:
        raise InputError(f"{what}: '{path.name}' has {data.ndim} dimensions {data.shape}; a 3D volume is needed")
    if say_non_finite(data, path.name, what):
        # (a processed image's background is often NaN: sampled, a NaN spreads to its neighbours)
        data = np.where(np.isfinite(data), data, 0.0).astype(data.dtype)
    volume.data = data
    return volume


def say_non_finite(data: np.ndarray, name: str, what: str) -> int:
    """How many voxels are NaN or infinite, said in the log when any are (they are read as 0)."""
    if not np.issubdtype(data.dtype, np.floating):
        return 0
    bad = int(data.size - np.count_nonzero(np.isfinite(data)))
    if bad:
        log.warning("%s: '%s' holds %d voxels that are not finite (NaN or infinite): read as 0", what, name, bad)
    return bad


def check_grid(shape, affine: np.ndarray, name: str, what: str) -> None:
    """The grid a header claims, judged before its voxels are read: a size no scan has (a damaged
    header: the reader would allocate it first), an affine that is not finite or is singular
    (every mapping to and from RAS would be NaN or fail)."""
    voxels = float(np.prod(np.asarray(shape, dtype=float)))  # (every axis: what would be allocated)
    if voxels > MAX_VOXELS:
        raise InputError(
            f"{what}: '{name}' claims {' x '.join(str(int(n)) for n in shape)} voxels "
            f"({voxels * 4 / 1e9:.0f} GB as float): not the grid of a scan (a damaged header?); export it again"
        )
    linear = np.asarray(affine, dtype=float)[:3, :3]
    if not np.isfinite(affine).all():
        raise InputError(
            f"{what}: '{name}' has an affine (voxel size, origin or orientation) that is not a finite number: "
            f"its header is damaged; export it again"
        )
    spacing = np.linalg.norm(linear, axis=0)
    if spacing.min() <= 0.0 or abs(np.linalg.det(linear)) < 1e-3 * float(np.prod(spacing)):
        raise InputError(
            f"{what}: '{name}' has a singular affine (voxel sizes {', '.join(f'{v:.3g}' for v in spacing)} mm, "
            f"its axes not independent): its header is damaged; export it again"
        )


def _read_nifti(path: Path, what: str) -> Volume:
    import nibabel as nib

    image = nib.load(str(path))  # (the header only: the voxels are read below, once judged)
    affine = np.array(image.affine, dtype=float)
    check_grid(image.shape, affine, path.name, what)
    return Volume(path, np.asanyarray(image.dataobj), affine, image.header)


def _read_nrrd(path: Path, what: str) -> Volume:
    import nrrd

    sizes = [int(n) for n in nrrd.read_header(str(path)).get("sizes", [])]
    check_grid(sizes, np.eye(4), path.name, what)  # (its size, before the voxels are read)
    data, header = nrrd.read(str(path))  # pynrrd: data[i, j, k], the file's axis order
    space = str(header.get("space", "")).lower()
    if space not in _NRRD_SPACES:
        raise InputError(
            f"'{path.name}': NRRD space '{header.get('space')}' is not supported; "
            f"save it from 3D Slicer (space RAS or LPS)"
        )
    directions = np.asarray(header["space directions"], dtype=float)
    directions = directions[~np.isnan(directions).any(axis=1)]  # a .seg.nrrd's layer axis has none
    layers = None
    if data.ndim == 4 and directions.shape[0] == 3:  # Slicer's layers first (kinds: list, domain x 3)
        if data.shape[0] == 1:
            data = data[0]
        else:
            layers = data
    flip = _NRRD_SPACES[space]
    affine = np.eye(4)
    affine[:3, :3] = flip @ directions.T  # columns: the i, j, k steps
    affine[:3, 3] = flip @ np.asarray(header["space origin"], dtype=float)
    check_grid((), affine, path.name, what)
    segments, segment_layers = _segments(header)
    return Volume(path, data, affine, header, segments if layers is None else {}, layers, segment_layers)


def _segments(header: dict) -> tuple[dict[int, str], dict[str, tuple[int, int]]]:
    """Slicer's .seg.nrrd metadata: SegmentN_Name, SegmentN_LabelValue and SegmentN_Layer, as
    (label value -> name, name -> (layer, label value))."""
    segments, layers, n = {}, {}, 0
    while f"Segment{n}_Name" in header:
        value = int(header.get(f"Segment{n}_LabelValue", n + 1))
        name = str(header[f"Segment{n}_Name"])
        segments[value] = name
        layers[name] = (int(header.get(f"Segment{n}_Layer", 0)), value)
        n += 1
    return segments, layers


def segment_names(volume: Volume) -> list[str]:
    """The segments a Slicer segmentation names (none for a plain label map)."""
    return list(volume.segment_layers) if volume.layers is not None else list(volume.segments.values())


def label_mask(volume: Volume, labels, what: str = "labels") -> np.ndarray:
    """The voxels (bool, [i, j, k]) in any of ``labels`` (values or segment names); in a
    layered segmentation a name is its layer's voxels of its value, as Slicer reads it, and a
    value is that value in any layer, refused where it is the value of segments in several
    layers. None: every labelled voxel."""
    if volume.layers is None:
        if labels is None:
            return volume.data > 0
        return np.isin(volume.data, label_values(volume, labels, what))
    if labels is None:
        return (volume.layers > 0).any(axis=0)
    mask = np.zeros(volume.data.shape, dtype=bool)
    for label in labels:
        if isinstance(label, str) and not label.isdigit():
            if label not in volume.segment_layers:
                known = ", ".join(f"'{n}'" for n in volume.segment_layers)
                raise InputError(f"{what}: no segment '{label}' in '{volume.path.name}'; its segments: {known}")
            layer, value = volume.segment_layers[label]
            mask |= volume.layers[layer] == value
        else:  # a value: ambiguous where segments of several layers share it (Slicer numbers each layer from 1)
            named = [n for n, (_, value) in volume.segment_layers.items() if value == int(label)]
            if len(named) > 1:
                raise InputError(
                    f"{what}: label {label} of '{volume.path.name}' is each of the segments "
                    f"{', '.join(repr(n) for n in named)} (in different layers): give the segment's name"
                )
            mask |= (volume.layers == int(label)).any(axis=0)
    return mask


def label_values(volume: Volume, labels, what: str = "labels") -> list[int]:
    """Label values from integers or segment names (a Slicer .seg.nrrd's SegmentN_Name)."""
    by_name = {name: value for value, name in volume.segments.items()}
    values = []
    for label in labels:
        if isinstance(label, str) and not label.isdigit():
            if label not in by_name:
                known = ", ".join(f"'{n}'" for n in by_name) or "none (the file names no segments)"
                raise InputError(f"{what}: no segment '{label}' in '{volume.path.name}'; its segments: {known}")
            values.append(by_name[label])
        else:
            values.append(int(label))
    return values


def write_like(reference: Volume, data: np.ndarray, path: str | Path, description: str | None = None) -> Path:
    """``data`` (the reference's shape) on the reference's grid, with its header, to ``path``
    (NIfTI or NRRD by suffix; a NIfTI reference may be written as NRRD and back);
    ``description``: what the values are and their unit (NIfTI's descrip, NRRD's content)."""
    path = Path(path)
    if data.shape != reference.data.shape:
        raise ValueError(f"data of shape {data.shape} on a grid of {reference.data.shape}")
    if not is_volume(path):
        raise InputError(f"-o: '{path.name}' is not a volume file name; {VOLUME_HELP}")
    suffix = ".nii.gz" if path.name.lower().endswith(".nii.gz") else path.suffix
    tmp = path.with_name(f".{path.name}.tmp{suffix}")
    try:
        if path.name.lower().endswith(NIFTI_SUFFIXES):
            _write_nifti(reference, data, tmp, description)
        else:
            _write_nrrd(reference, data, tmp, description)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _write_nifti(reference: Volume, data: np.ndarray, path: Path, description: str | None = None) -> None:
    import nibabel as nib

    header = reference.header.copy() if reference.kind == "nifti" else None
    image = nib.Nifti1Image(data, reference.affine, header)
    if header is not None:
        image.set_data_dtype(data.dtype)
    if description is not None:
        image.header["descrip"] = description.encode("ascii", "replace")[:79]
    nib.save(image, str(path))


def _write_nrrd(reference: Volume, data: np.ndarray, path: Path, description: str | None = None) -> None:
    import nrrd

    if reference.kind == "nrrd" and len(np.asarray(reference.header["space directions"])) == 3:
        header = {k: v for k, v in reference.header.items() if k not in ("type", "dimension", "sizes")}
    else:  # from NIfTI (or a layered .seg.nrrd): the grid in LPS, as Slicer writes it
        header = {
            "space": "left-posterior-superior",
            "space directions": (LPS_TO_RAS @ reference.affine[:3, :3]).T,
            "space origin": LPS_TO_RAS @ reference.affine[:3, 3],
            "kinds": ["domain"] * 3,
            "encoding": "gzip",
        }
    if description is not None:
        header = {**header, "content": description}
    nrrd.write(str(path), data, header, index_order="F")
