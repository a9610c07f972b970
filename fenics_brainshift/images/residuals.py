"""Whether residuals are what the stated measurement noise allows: the chi-square test the fit
and the update both report with."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# residuals whose chi-square against the stated noise has an upper tail below this probability
# cannot be the noise's doing
UNEXPLAINED_P = 1e-3
# ... and only past this many times the stated noise per coordinate: a stated noise is never exact
# (both points of a pair noisy make sqrt(2); 2000 scanned points at 1.04x the noise reach p < 1e-3)
UNEXPLAINED_RATIO = 2.0


@dataclass
class ChiSquare:
    chi2: float
    dof: int
    p: float  # the probability of a chi-square this large from the noise alone
    ratio: float  # the residual per coordinate over the noise

    @property
    def unexplained(self) -> bool:
        return self.p < UNEXPLAINED_P and self.ratio > UNEXPLAINED_RATIO

    def words(self, noise: float) -> str:
        return (
            f"{self.ratio:.1f}x a stated noise of {noise * 1e3:g} mm per coordinate (chi-square {self.chi2:.0f} for "
            f"{self.dof} coordinates, p = {self.p:.1e})"
        )


def chi_square(residual: np.ndarray, noise: float, coordinates, fitted: int = 0) -> ChiSquare:
    """The residuals (m; a pair's distance covers 3 coordinates, a distance to a surface 1, as
    ``coordinates`` says per point or for all) against the noise (m per coordinate), with
    ``fitted`` parameters taken off the degrees of freedom."""
    from scipy.special import gammaincc

    chi2 = float(np.sum((np.asarray(residual) / noise) ** 2))
    dof = max(int(np.sum(np.broadcast_to(coordinates, np.shape(residual)))) - fitted, 0)
    p = float(gammaincc(dof / 2, chi2 / 2)) if dof else 1.0  # (the chi-square's upper tail)
    return ChiSquare(chi2, dof, p, float(np.sqrt(chi2 / dof)) if dof else 0.0)
