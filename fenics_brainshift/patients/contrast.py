"""Which contrast a patient's scan is: told (--contrast), read from the DICOM series'
description or the file's name, and measured after the registration (the sign of the
correlation with the T1 template in the brain found: a T2 or PD is bright where a T1 is dark).

The registration measures mutual information and the quality gate the correlation ratio, so
neither needs the contrast; it is reported, so that a user sees what the scan was taken for,
and a post-contrast T1 (bright vessels, dura and enhancing tumour) is named as such.
"""

from __future__ import annotations

import re
from pathlib import Path

CONTRASTS = ("t1", "t1c", "t2", "flair", "pd")
NAMES = {"t1": "native T1", "t1c": "post-contrast T1", "t2": "T2", "flair": "FLAIR", "pd": "proton density"}
T1_LIKE = ("t1", "t1c")
SIGN = 0.2  # |correlation with the T1 template| below this: the measured contrast is unclear

# word patterns in a series description or a file name, first match wins
# word patterns in a series description or a file name, first match wins; t1/t2 not inside a
# longer word or number ("patient12", Siemens' "iPAT2")
_PATTERNS = [
    ("flair", r"flair|\bdark.?fluid"),
    ("pd", r"\bpd\b|pdw|proton"),
    (
        "t1c",
        r"(?<![a-z0-9])t1c|(?<![a-z0-9])t1.?ce\b|\bce.?t1|\+ ?c\b|gad|\bgd\b|post.?(gd|contrast|con)|"
        r"(?<![a-z0-9])t1.?post|\bpost.?t1|(?<![a-z0-9])t1.*\bpost\b|contrast|\bkm\b|\bmdc\b",
    ),
    ("t2", r"(?<![a-z0-9])t2(?![0-9])|space.*t2|\bciss\b|\bfiesta\b"),
    ("t1", r"(?<![a-z0-9])t1(?![0-9])|mprage|mp.?rage|spgr|bravo|\btfe\b|\bvibe\b"),
]


def described_contrast(path: str | Path, metadata: dict[str, str] | None = None) -> tuple[str | None, str]:
    """(contrast, what it was read from) from a DICOM series' description, protocol and
    contrast agent tags (``metadata``, tag -> value), else the file or folder name; None if
    nothing says."""
    metadata = metadata or {}
    agent = metadata.get("0018|0010", "").strip()
    for tag, what in (("0008|103e", "series description"), ("0018|1030", "protocol name")):
        text = metadata.get(tag, "").strip()
        found = _match(text)
        if found:
            if found == "t1" and agent:
                return "t1c", f"{what} '{text}' with contrast agent '{agent}'"
            return found, f"{what} '{text}'"
    if agent:
        return "t1c", f"contrast agent '{agent}'"
    name = Path(path).name
    found = _match(name)
    return (found, f"the name '{name}'") if found else (None, "nothing")


def _match(text: str) -> str | None:
    lowered = re.sub(r"[_\-.]", " ", text.lower())
    for contrast, pattern in _PATTERNS:
        if re.search(pattern, lowered):
            return contrast
    return None


def disagrees(contrast: str | None, measured: str) -> bool:
    """A contrast said (or read) that the measurement contradicts: a T1 measured T2-like, a T2
    measured T1-like (PD and FLAIR fall either way)."""
    return (contrast in T1_LIKE and measured == "T2-like") or (contrast == "t2" and measured == "T1-like")


def measured_family(correlation: float) -> str:
    """'T1-like', 'T2-like' or 'unclear' from the correlation with the T1 template in the brain."""
    if correlation >= SIGN:
        return "T1-like"
    if correlation <= -SIGN:
        return "T2-like"
    return "unclear"
