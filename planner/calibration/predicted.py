"""The pose accuracy a geometry calibration predicts: the parameters' uncertainty carried to a commanded pose.

The planner commands a pose P through a profile with parameters p̂: the actuators q = IK(P; p̂), and the machine
reaches FK(q; p) with its true parameters p. To first order the error is

    e(q) = FK(q; p) − FK(q; p̂) ≈ J(q) (p − p̂),        J = ∂FK/∂p at (q, p̂)

(:meth:`~planner.calibration.parametric.ParametricModel.batch`, the calibration's own Jacobian), so its
covariance is J Σ Jᵀ with Σ the covariance of p − p̂:

* **calibrated**: the fit's covariance of the identified directions (residual variance times the inverse
  information, plus the AD map's whole-count rounding: :attr:`CalibrationResult.covariance_scaled`) plus the tape
  prior along the directions it cannot identify, σ₀² (I − B Bᵀ) in scaled units (B: the identified basis;
  σ₀ = 1/√3 of a tape size, :data:`~planner.calibration.solve.PRIOR_SIGMA_SCALED`) — per parameter this is the
  σ the report prints (:attr:`CalibrationResult.std_total`), here as the whole matrix;
* **uncalibrated** (the nominal, tape-measured profile): the tape prior alone, σ₀² I.

Per DOF (x, z, roll, pitch) and pose the error is then Gaussian with σᵢ; the predicted p95 over the workspace is
the t with mean over poses of P(|N(0, σᵢ²)| ≤ t) = 0.95 (:func:`mixture_quantile`), the figure the calibration
bench measures against the truth (``bench/calibration_bench.py``, "no quantisation").

Not in it: what the geometry does not hold — the references' whole AD counts and where a piston stops within
its count (about ±1.9 mm of z on the thesis profile) and the pin play (docs/commissioning.md, the floors). Linear:
a direction known only to several tape sizes moves the error at second order (docs/commissioning.md, the lift
chain's bias), which this does not hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.calibration.parameters import CalibrationError
from planner.calibration.parametric import POSE_ROWS, ParametricModel
from planner.calibration.solve import PRIOR_SIGMA_SCALED, CalibrationResult
from planner.model.types import CONTROLLED_POSE_NAMES

__all__ = [
    "PREDICTED_QUANTILE",
    "PredictedAccuracy",
    "calibrated_covariance",
    "mixture_quantile",
    "predict_accuracy",
    "tape_covariance",
]

#: the share of commanded poses the predicted bound holds for (the issue's p95)
PREDICTED_QUANTILE = 0.95
_ROWS = np.array([POSE_ROWS[k] for k in CONTROLLED_POSE_NAMES])


@dataclass(frozen=True)
class PredictedAccuracy:
    """Per pose and DOF the predicted error's σ (``sigma`` (M, 4): x, z [m], roll, pitch [rad]) at ``readings``
    (M, 5) [SI]; :attr:`p95` the predicted 95th percentile of |error| over those poses, per DOF."""

    readings: np.ndarray
    sigma: np.ndarray

    @property
    def p95(self) -> np.ndarray:
        """Per DOF (x, z, roll, pitch) [m, rad]: the |error| that 95 % of the poses' errors stay within."""
        return np.array([mixture_quantile(self.sigma[:, k], PREDICTED_QUANTILE) for k in range(self.sigma.shape[1])])

    def as_dict(self) -> dict[str, float]:
        """``{"x_m", "z_m", "roll_rad", "pitch_rad"}`` of :attr:`p95` (JSON-ready, SI with the unit in the name)."""
        unit = {"x": "m", "z": "m", "roll": "rad", "pitch": "rad"}
        return {f"{k}_{unit[k]}": float(v) for k, v in zip(CONTROLLED_POSE_NAMES, self.p95, strict=True)}


def mixture_quantile(sigmas: np.ndarray, q: float) -> float:
    """The t with mean_i P(|N(0, σᵢ²)| ≤ t) = ``q`` (0 < q < 1): the q-quantile of |e| when e is drawn from the
    poses' zero-mean Gaussians with equal weight. P(|N(0, σ²)| ≤ t) = erf(t / (σ √2)); bisection to 1e-12 of
    the bracket [0, max σ · 10]."""
    s = np.asarray(sigmas, dtype=float).reshape(-1)
    if s.size == 0 or not np.all(np.isfinite(s)) or np.any(s < 0.0):
        raise CalibrationError("sigmas must be a non-empty array of finite numbers ≥ 0")
    if not 0.0 < q < 1.0:
        raise CalibrationError(f"q must lie in (0, 1), got {q!r}")
    top = float(np.max(s))
    if top == 0.0:
        return 0.0
    pos = s[s > 0.0]
    zero_share = 1.0 - pos.size / s.size  # poses without error: |e| = 0 always

    def cdf(t: float) -> float:
        return zero_share + float(np.sum([math.erf(t / (v * math.sqrt(2.0))) for v in pos])) / s.size

    lo, hi = 0.0, 10.0 * top
    while hi - lo > 1e-12 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cdf(mid) < q else (lo, mid)
    return 0.5 * (lo + hi)


def calibrated_covariance(result: CalibrationResult) -> np.ndarray:
    """Σ of the calibrated parameters' errors, (n, n) in scaled units (module docstring): the fit's covariance
    plus the tape prior along the directions it cannot identify."""
    n = len(result.names)
    basis = result.basis if result.basis.size else np.zeros((n, 0))
    unidentified = np.eye(n) - basis @ basis.T
    return np.asarray(result.covariance_scaled, dtype=float) + PRIOR_SIGMA_SCALED**2 * unidentified


def tape_covariance(n_params: int) -> np.ndarray:
    """Σ of the tape-measured (nominal) parameters' errors, scaled units: σ₀² I (each uniform within ± a tape
    size)."""
    return PRIOR_SIGMA_SCALED**2 * np.eye(n_params)


def predict_accuracy(
    model: ParametricModel,
    values: np.ndarray,
    covariance_scaled: np.ndarray,
    readings: np.ndarray,
    *,
    side: float = 0.0,
) -> PredictedAccuracy:
    """The predicted pose error at ``readings`` (M, 5) [SI] of a profile with parameters ``values`` [SI] whose
    errors have covariance ``covariance_scaled`` (n, n; scaled units ``(p − p̂)/scale``): σ per pose and DOF,
    sqrt(diag(Jₛ Σ Jₛᵀ)) with Jₛ = J · diag(scale) (module docstring). ``side``: the side every goto ends from
    (−1 rising: the profile's final approach ``below``; +1 ``above``; 0 none): the planner aims by the fitted
    lag of the pin play, so the lag's own error adds there as side · δlag."""
    if side not in (-1.0, 0.0, 1.0):
        raise CalibrationError(f"side must be -1, 0 or 1, got {side!r}")
    ps = model.params
    cov = np.asarray(covariance_scaled, dtype=float)
    if cov.shape != (len(ps), len(ps)) or not np.all(np.isfinite(cov)):
        raise CalibrationError(f"covariance must be a finite ({len(ps)}, {len(ps)}) matrix, got shape {cov.shape}")
    r = np.asarray(readings, dtype=float)
    _, jac = model.batch(r, values, jacobian=True, sides=np.full(r.shape[0] if r.ndim == 2 else 0, float(side)))
    assert jac is not None
    js = jac[:, _ROWS, :] * ps.scale[None, None, :]  # (M, 4, n)
    var = np.einsum("mdi,ij,mdj->md", js, cov, js)
    return PredictedAccuracy(r, np.sqrt(np.maximum(var, 0.0)))
