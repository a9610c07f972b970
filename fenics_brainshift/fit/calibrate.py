"""Fit the parameters to the measured points: robust nonlinear least squares on the forward model.

scipy's trust-region reflective least squares within the parameters' bounds, the residuals
point to point (3 per point) or point to surface (1 per point), with a soft-l1 loss whose
scale is the measurement noise (points far off count linearly, not squared: a few outliers
do not pull the fit). The Jacobian is by forward differences, one settled state per parameter
(each re-solve reuses the one factor and starts from the last answer).

Uncertainty from the Jacobian at the solution: the robust sandwich covariance H^-1 B H^-1 of
the soft-l1 fit, its weights the same in H and B (_uncertainty says how). A parameter the points do not constrain
(its column of J near zero, or a combination of columns near dependence) shows as a standard
deviation comparable to its bounds and is reported as "not constrained", not as a number.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from ..errors import InputError, SolverError
from ..images.residuals import chi_square
from ..images.targets import Target
from ..outputs.points import PointEvaluator
from .forward import ForwardModel
from .parameters import Parameter

# relative step of the finite differences, on the scaled parameters (x / Parameter.scale)
DIFFERENCE_STEP = 1e-3
# a standard deviation above this fraction of the bound range: the points do not constrain it
UNCONSTRAINED = 0.25
# the residual (m) of parameters with no settled state: far worse than any fit, so the trust
# region shrinks away from them
NO_EQUILIBRIUM = 1.0
# measured points whose median distance from the prediction is past this fraction of the body's
# diagonal (70 mm for the brain; shifts are at most 20-30 mm) are in another frame or unit
FAR_FROM_PREDICTION = 0.25


@dataclass
class FitResult:
    """A calibration: the fitted values with their standard deviations and whether the points
    constrain each, the residuals before and after (m), the settled states it took and its time."""

    parameters: list[Parameter]
    values: np.ndarray
    std: np.ndarray
    constrained: list[bool]
    residuals: np.ndarray  # per point, m (norm of the 3 components, or the distance)
    prior_residuals: np.ndarray
    solves: int
    seconds: float
    message: str
    singular_values: list[float] = field(default_factory=list)
    without_equilibrium: int = 0  # evaluations whose parameters gave no settled state
    at_bound: list[str | None] = field(default_factory=list)  # "lower" / "upper": the points want it beyond
    warning: str | None = None  # the fit does not explain the data

    def as_dict(self) -> dict:
        bounds = self.at_bound or [None] * len(self.parameters)
        out = {
            "parameters": {
                p.name: {
                    "prior": p.prior,
                    "fitted": float(v),
                    "std": (float(s) if c else None),
                    "constrained": c,
                    "at_bound": b,
                    "bounds": [p.lower, p.upper],
                    "unit": p.unit,
                }
                for p, v, s, c, b in zip(self.parameters, self.values, self.std, self.constrained, bounds)
            },
            "residual_rms_mm": float(np.sqrt(np.mean(self.residuals**2)) * 1e3),
            "residual_max_mm": float(np.abs(self.residuals).max() * 1e3),
            "prior_residual_rms_mm": float(np.sqrt(np.mean(self.prior_residuals**2)) * 1e3),
            "residuals_mm": [float(r * 1e3) for r in self.residuals],
            "settled_states_solved": self.solves,
            "seconds": self.seconds,
            "optimiser": self.message,
            "evaluations_without_equilibrium": self.without_equilibrium,
            "scaled_jacobian_singular_values": self.singular_values,
        }
        if self.warning:
            out["warning"] = self.warning
        return out


def fit(forward: ForwardModel, target: Target, parameters: list[Parameter], noise: float = 1e-3) -> FitResult:
    """The parameters that best explain the target; noise (m): the measurement's size, the
    robust loss's scale."""
    if not noise > 0:
        raise InputError(f"--noise must be > 0 mm (got {noise * 1e3:g})")
    names = [p.name for p in parameters]
    scale = np.array([p.scale for p in parameters])
    lower = np.array([p.lower for p in parameters]) / scale
    upper = np.array([p.upper for p in parameters]) / scale
    t0, solves0 = time.perf_counter(), forward.solves

    no_equilibrium: list[np.ndarray] = []  # parameters tried that have no settled state

    def residuals(x: np.ndarray) -> np.ndarray:
        try:
            forward.solve(dict(zip(names, x * scale)))
        except SolverError:  # a finite-deformation body too soft there: a bad step, not the end
            if prior is None:
                raise
            no_equilibrium.append(x * scale)
            return np.full_like(prior, NO_EQUILIBRIUM)
        if target.pre is not None:
            return (forward.positions(target.pre) - target.measured).ravel()
        return forward.signed_distances(target.measured)

    if target.pre is not None:  # a point outside the body would be extrapolated, silently
        outside = PointEvaluator(forward.model.mesh, target.pre).far_outside()
        if len(outside):
            labels = ", ".join(target.labels[i] for i in outside[:5])
            raise InputError(
                f"--pre: {len(outside)} point(s) ({labels}) lie outside the body, farther than a cell "
                f"from it: a frame or unit slip (RAS or LPS, mm)? or points not on the brain"
            )
    check_enough(target, len(parameters))
    x0 = np.array([p.prior for p in parameters]) / scale
    prior = None
    prior = residuals(x0)  # the scene itself must have a settled state
    _check_near(forward, target, _per_point(prior, target))
    result = least_squares(
        residuals,
        x0,
        bounds=(lower, upper),
        loss="soft_l1",
        f_scale=noise,
        method="trf",
        diff_step=DIFFERENCE_STEP,
        x_scale=1.0,
    )
    final = residuals(result.x)  # the state left behind is the fitted one
    values = result.x * scale
    std, constrained, singular = _uncertainty(result, final, scale, upper - lower, noise)
    per_point = _per_point(final, target)
    # a parameter on its bound is where the points would take it past: not a measurement (the
    # trust-region iterates stay strictly inside, so "on" is within 1e-4 of the range too)
    near = 1e-4 * (upper - lower)
    at_bound = [
        ("lower" if a < 0 or x - lo <= d else "upper" if a > 0 or hi - x <= d else None)
        for a, x, lo, hi, d in zip(result.active_mask, result.x, lower, upper, near)
    ]
    constrained = [c and b is None for c, b in zip(constrained, at_bound)]
    rms = float(np.sqrt(np.mean(per_point**2)))
    warning = None
    test = chi_square(per_point, noise, 3 if target.pre is not None else 1, fitted=len(parameters))
    if test.unexplained:
        warning = (
            f"the model does not explain the data: the fitted residual RMS {rms * 1e3:.3g} mm, {test.words(noise)}; "
            f"usually a frame or unit slip (RAS or LPS, mm), points mismatched between --pre and --target, another "
            f"patient's points, or a cause the parameters lack"
        )
    return FitResult(
        parameters,
        values,
        std,
        constrained,
        per_point,
        _per_point(prior, target),
        forward.solves - solves0,
        time.perf_counter() - t0,
        result.message,
        singular,
        len(no_equilibrium),
        at_bound,
        warning,
    )


def _check_near(forward: ForwardModel, target: Target, prior: np.ndarray) -> None:
    """Measured points half of them farther from the scene's prediction than a quarter of the
    body (a shift is at most a few centimetres) are in another frame or unit: refused, as a fit
    to them only reports that the model does not explain them."""
    from ..meshing.extent import body_diagonal

    body = body_diagonal(forward.model.mesh)
    median = float(np.median(prior))
    if median > FAR_FROM_PREDICTION * body:
        what = "the predicted brain surface" if target.pre is None else "where --pre's points are predicted"
        raise InputError(
            f"--target: half the points lie more than {median * 1e3:.3g} mm from {what} (the body is "
            f"{body * 1e3:.3g} mm across): a frame or unit slip (RAS or LPS, mm; --frame for a CSV or "
            f"an untagged surface), or points of another body"
        )


def _per_point(r: np.ndarray, target: Target) -> np.ndarray:
    return np.linalg.norm(r.reshape(-1, 3), axis=1) if target.pre is not None else np.abs(r)


def check_enough(target, count: int) -> None:
    """InputError for fewer measured values than parameters (they would be fitted to anything,
    each reported with a standard deviation as if measured)."""
    values_per_point = 1 if target.pre is None else 3  # a distance, or a displacement's 3 components
    if values_per_point * len(target.measured) < count:
        what = "points on the surface, a distance each" if target.pre is None else "point pairs, 3 values each"
        raise InputError(
            f"--target: {len(target.measured)} {what}, cannot fit {count} parameters: give more "
            f"points or fewer --params"
        )


def _uncertainty(result, r: np.ndarray, scale: np.ndarray, span: np.ndarray, noise: float):
    """(std of each parameter, whether it is constrained, singular values of the scaled J).

    The robust (M-estimator) sandwich covariance H^-1 B H^-1 of the soft-l1 fit: with
    z = (r / noise)^2, H = J^T diag(rho' + 2 rho'' z) J (scipy's result.jac is J with its rows
    scaled by the square root of that weight, (1 + z)^(-3/4) for soft-l1) and B = J^T diag(psi^2) J,
    psi = rho'(z) r = r / sqrt(1 + z), times m / (m - n). Each psi^2 is at least (noise / 3)^2: a
    perfect fit is not a certainty. (s^2 of the unweighted residuals with scipy's weighted J
    reported 1.33 times the scatter of fits over noise draws: tests/test_fit_spread.py.)"""
    Jw = result.jac  # d r / d (x / scale), rows times sqrt(w)
    m, n = Jw.shape
    z = (r / noise) ** 2
    w = np.maximum((1.0 + z) ** -1.5, np.finfo(float).eps)  # rho' + 2 rho'' z of soft-l1
    psi2 = np.maximum(r * r / (1.0 + z), noise**2 / 9.0)
    J = Jw / np.sqrt(w)[:, None]
    _, sv, vt = np.linalg.svd(Jw, full_matrices=False)
    tiny = sv <= 1e-12 * sv.max(initial=0.0)
    H_pinv = (vt.T * np.where(tiny, 0.0, 1.0 / np.where(tiny, 1.0, sv) ** 2)) @ vt
    B = (J.T * psi2) @ J * (m / max(m - n, 1))
    cov = H_pinv @ B @ H_pinv
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    # a direction with (near-)zero singular value leaves the parameters along it free
    free = np.abs(vt[tiny]).max(axis=0) > 0.1 if tiny.any() else np.zeros(n, dtype=bool)
    constrained = [bool((not f) and s < UNCONSTRAINED * w_) for f, s, w_ in zip(free, std, span)]
    return std * scale, constrained, [float(v) for v in sv]
