"""Units of length a scene's mesh or a surface file may be in, as factors to metres: the one
table the scene's checks and the meshers' unit guesses share."""

from __future__ import annotations

LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
