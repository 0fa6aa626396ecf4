"""Nonlinear least squares over the uncertain parameters: Levenberg–Marquardt with CasADi Jacobians.

Residuals are the measured outputs minus the model's, divided by the instrument's σ (positions
``sigma_position_m``, angles ``sigma_angle_rad``); the unknowns are the scaled deltas
``u = (p − nominal) / scale`` (scale = the parameter's tape-measure uncertainty). So a singular
value s of the weighted, scaled Jacobian says: a change of one tape size along its right singular
vector changes the fit by s σ. Directions with s < ``min_singular`` (default 1: the data see a tape
error there by less than one σ) cannot be identified: they stay at their nominal values and are
named in the result. The solver works in the identifiable subspace (fixed from the SVD at the
nominal parameters and refreshed once at the solution).

Standard deviations come from the residual variance σ̂² = |r|² / (m − k) (m observations, k
identified directions) times the inverse information of the identified directions, plus what rounding the
AD map to the profile's whole counts adds (each count uniform within ± 0.5: 1/√12 count, the GUM's
resolution term, carried through the geometry's refit); with exact measurements and no rounding they are
~0. That ``std`` holds with the unidentified directions at nominal: a parameter only partly in the
identified subspace is uncertain along the rest by its tape error, so the reported σ
(:attr:`CalibrationResult.std_total`) adds the tape prior of the unidentified part, (1 − share) · (scale/√3)²
(the tape error: uniform within ± scale). A parameter wholly unidentified (share below
:data:`UNIDENTIFIED_SHARE`: kept at nominal) has no σ (NaN; ``None`` in :meth:`CalibrationResult.as_dict`).
A fit needs at least as many residual degrees of freedom m − k as identified directions k to check itself
(σ̂ from one or two spare values says nothing): :func:`check_residual_dof` refuses fewer.

**The tape prior** (``tape_prior=True``, the default; ``hitch calibrate geometry --no-tape-prior`` leaves it
out): the profile's values were tape-measured, each within ± its scale (σ = scale · :data:`PRIOR_SIGMA_SCALED`).
That knowledge is weighed in along the identified directions (a maximum a posteriori fit): after the least-squares
fit has given σ̂, the fit is repeated, from its solution and from the nominal values (the lower cost kept: a least
squares gone far along weak directions is no start the prior's fit comes back from), with the rows w · u appended,
w = σ̂ / PRIOR_SIGMA_SCALED (the measurements' noise taken as σ̂ times the σ given: the prior weighs as much against
the data as their own scatter says; with exact measurements σ̂ → 0 and the fit is the least-squares one, a known
perturbation recovered to solver tolerance). The covariance is then σ̂² (Bᵀ(Jᵀ J + W²) B)⁻¹ in the identified
coordinates B (the posterior's). In a direction the poses see at singular value s the prior adds 3 to s² (1.59² = 2.5
for the lift-arm pivot's fore-aft position of the 20 planned poses): it halves the variance the noise gives that
direction (its σ 1/√(s² + 3) tape sizes instead of 1/s: two thirds), and with it the curvature's shift of the
directions coupled to it (the lift chain's, docs/commissioning.md); no reported σ exceeds the tape's own. The lag
(``lag.*``) has no prior: the play's band is not an error around a nominal value.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from planner.calibration.measurements import MEASURED_COLUMNS, MeasurementSet
from planner.calibration.parameters import CalibrationError, ParameterSet
from planner.calibration.parametric import ParametricModel
from planner.model.types import KinematicsError
from planner.profiles.hitch import profile_from_dict

__all__ = [
    "FIT_SIGMA_HAT",
    "IDENTIFIED_SHARE",
    "OUTLIER_SIGMA",
    "PRIOR_SIGMA_SCALED",
    "ROUNDING_VARIANCE_COUNTS2",
    "UNIDENTIFIED_SHARE",
    "WEAKLY_IDENTIFIED_SHARE",
    "CalibrationProblem",
    "CalibrationResult",
    "build_calibration_problem",
    "check_residual_dof",
    "identifiable_basis",
    "identification_status",
    "largest_residuals",
    "outlying_rows",
    "solve_calibration",
    "weak_fit_cause",
]

_ANGLE_ROWS = np.array([c in ("roll", "pitch", "yaw") for c in MEASURED_COLUMNS])
#: a parameter whose identified share is below this lies in unidentified combinations only: it has no std
UNIDENTIFIED_SHARE = 1e-6
#: at or above this the data determine a parameter alone (its std holds whatever the rest)
IDENTIFIED_SHARE = 0.995
#: below this share (and at or above :data:`UNIDENTIFIED_SHARE`) a parameter is "weakly identified": its value
#: moves only with the identified combinations it is part of and its σ is mostly its tape error (its conditional
#: std read as "± 0.009 mm" of a value 54 std off the truth: a commissioning trial)
WEAKLY_IDENTIFIED_SHARE = 0.5


def identification_status(share: float) -> str:
    """The words the text report and the profile's provenance both use for a parameter whose identified share
    (0…1, :attr:`CalibrationResult.identified_share`) is ``share``:

    * ``"not identified"`` (share < :data:`UNIDENTIFIED_SHARE`): it lies in unidentified combinations only and
      is kept at its nominal value; no σ;
    * ``"weakly identified"`` (below :data:`WEAKLY_IDENTIFIED_SHARE`): it lies mostly in unidentified
      combinations; its value moves only with the identified ones it is part of, its σ is mostly its tape error;
    * ``"partly identified"`` (below :data:`IDENTIFIED_SHARE`): its σ includes the tape error of its
      unidentified part;
    * ``"identified"``: the data determine it alone.
    """
    if not share >= UNIDENTIFIED_SHARE:  # NaN too
        return "not identified"
    if share < WEAKLY_IDENTIFIED_SHARE:
        return "weakly identified"
    if share < IDENTIFIED_SHARE:
        return "partly identified"
    return "identified"


#: the σ of a parameter's tape error in units of its scale (uniform within ± scale: 1/√3), the prior of the
#: directions the data cannot identify
PRIOR_SIGMA_SCALED = 1.0 / math.sqrt(3.0)
#: σ̂ up to which the residuals agree with the σ given (above it the measurements are suspect)
FIT_SIGMA_HAT = 3.0


@dataclass(frozen=True)
class CalibrationProblem:
    """A calibration problem: the model, the measurements and the weights (σ per output row)."""

    model: ParametricModel
    data: MeasurementSet
    sigma: np.ndarray  # (15,) σ of each output row [m or rad]
    seeds: np.ndarray

    @property
    def params(self) -> ParameterSet:
        return self.model.params

    def residuals(self, u: np.ndarray, *, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Weighted residuals (m,) and their Jacobian (m, n) in scaled units at scaled deltas ``u``."""
        ps = self.params
        p = ps.nominal + ps.scale * u
        y, j = self.model.batch(self.data.readings, p, jacobian=jacobian, seeds=self.seeds, sides=self.data.side_vector)
        m = self.data.mask
        w = 1.0 / self.sigma
        r = ((y - np.nan_to_num(self.data.values)) * w)[m]
        if j is None:
            return r, None
        js = (j * w[None, :, None] * ps.scale[None, None, :])[m]
        return r, js


def build_calibration_problem(
    model: ParametricModel,
    data: MeasurementSet,
    *,
    sigma_position_m: float = 0.001,
    sigma_angle_rad: float = 0.001,
) -> CalibrationProblem:
    """The least-squares problem of ``data`` on ``model`` (checks sizes, σ in (0, 1])."""
    for name, v in (("sigma_position_m", sigma_position_m), ("sigma_angle_rad", sigma_angle_rad)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and 0.0 < v <= 1.0):
            raise CalibrationError(f"{name} must be a number in (0, 1], got {v!r}")
    if not isinstance(data, MeasurementSet):
        raise CalibrationError(f"data must be a MeasurementSet, got {type(data).__name__}")
    sigma = np.where(_ANGLE_ROWS, float(sigma_angle_rad), float(sigma_position_m))
    return CalibrationProblem(model, data, sigma, model.seeds(data.readings))


def identifiable_basis(js: np.ndarray, min_singular: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(singular values (n,), identified right singular vectors (n, k), unidentified (n, n − k)) of ``js``."""
    n = js.shape[1]
    _, s, vt = np.linalg.svd(js, full_matrices=True)
    s_full = np.zeros(n)
    s_full[: s.size] = s
    smax = s_full[0] if n else 0.0
    keep = (s_full >= min_singular) & (s_full >= 1e-10 * smax)
    return s_full, vt[keep].T, vt[~keep].T


@dataclass(frozen=True)
class CalibrationResult:
    """The outcome of a geometry calibration (SI; parameters in :attr:`names` order).

    ``values`` the calibrated parameters (unidentified directions at nominal), ``std`` their standard
    deviations, ``singular_values`` of the weighted scaled Jacobian at the solution, ``identified`` the
    number of identified directions, ``unidentifiable`` the unidentified combinations in words (with
    their singular values), ``residual_rms_position_m`` / ``residual_rms_angle_rad`` the measured minus
    calibrated model, ``residual_sigma`` σ̂ (≈ 1 when the instrument's σ was right).
    """

    names: tuple[str, ...]
    nominal: np.ndarray
    values: np.ndarray
    std: np.ndarray
    scale: np.ndarray
    singular_values: np.ndarray
    identified: int
    unidentifiable: tuple[str, ...]
    basis: np.ndarray  # (n, k) identified directions in scaled units
    covariance_scaled: np.ndarray  # (n, n) covariance of the scaled deltas
    residual_rms_position_m: float
    residual_rms_angle_rad: float
    residual_rms_nominal_position_m: float
    residual_rms_nominal_angle_rad: float
    residual_sigma: float
    n_poses: int
    n_observations: int
    iterations: int
    converged: bool
    duration_s: float
    min_singular: float = 1.0
    tape_prior: bool = False
    #: the least-squares fit's values (before the tape prior and the AD map's rounding; None: not given). The prior
    #: pulls a parameter toward the profile's value, so how far the measurements alone move it says more about a
    #: wrong profile value or a slip in the file: a truth 6 tape sizes off read 6.3 tape sizes by least squares and
    #: 4.8 with the prior, under the 5 at which the CLI refuses a fit (a review)
    values_least_squares: np.ndarray | None = None

    @property
    def identified_share(self) -> np.ndarray:
        """Per parameter, the share (0…1) of its scaled unit direction that lies in the identified subspace:
        1 — the data determine it and ``std`` is its standard deviation; 0 — it lies in unidentified
        combinations only (kept nominal; ``std`` ≈ 0 says nothing, :attr:`std_total` is NaN); between — ``std``
        holds with the unidentified combinations at nominal, :attr:`std_total` adds their tape error."""
        return np.sum(self.basis**2, axis=1) if self.basis.size else np.zeros(len(self.names))

    @property
    def std_total(self) -> np.ndarray:
        """Per parameter, the σ to report: ``std`` (the identified part's, with the rest at nominal) plus the
        tape prior of its unidentified part, (1 − share)·(scale·:data:`PRIOR_SIGMA_SCALED`)²; NaN for one the
        data do not see at all (share < :data:`UNIDENTIFIED_SHARE`: kept nominal, no σ). The identified part's
        alone read 0.44 mm for a parameter 2.9 mm off the truth in 10 of 10 twins (80 % identified)."""
        share = self.identified_share
        prior = np.clip(1.0 - share, 0.0, 1.0) * (self.scale * PRIOR_SIGMA_SCALED) ** 2
        total = np.sqrt(self.std**2 + prior)
        return np.where(share >= UNIDENTIFIED_SHARE, total, np.nan)

    def as_dict(self) -> dict[str, object]:
        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "parameters": {
                n: {
                    "nominal": float(a),
                    "value": float(v),
                    "std": num(t),  # the reported σ (std_total): None where not identified
                    "std_identified_part": num(s) if math.isfinite(t) else None,
                    "identified_share": float(h),
                    "status": identification_status(float(h)),  # the words of the text and of the provenance
                }
                for n, a, v, s, t, h in zip(
                    self.names, self.nominal, self.values, self.std, self.std_total, self.identified_share, strict=True
                )
            },
            "singular_values": [float(s) for s in self.singular_values],
            "identified": self.identified,
            "unidentifiable": list(self.unidentifiable),
            "residual_rms_position_m": self.residual_rms_position_m,
            "residual_rms_angle_rad": self.residual_rms_angle_rad,
            "residual_rms_nominal_position_m": self.residual_rms_nominal_position_m,
            "residual_rms_nominal_angle_rad": self.residual_rms_nominal_angle_rad,
            "residual_sigma": self.residual_sigma,
            "n_poses": self.n_poses,
            "n_observations": self.n_observations,
            "residual_dof": self.n_observations - self.identified,
            "iterations": self.iterations,
            "converged": self.converged,
            "duration_s": self.duration_s,
            "tape_prior": self.tape_prior,
        }


def _rms(problem: CalibrationProblem, r: np.ndarray) -> tuple[float, float]:
    raw = r * np.broadcast_to(problem.sigma, problem.data.mask.shape)[problem.data.mask]
    ang = np.broadcast_to(_ANGLE_ROWS, problem.data.mask.shape)[problem.data.mask]
    pos = raw[~ang]
    a = raw[ang]
    return (
        float(np.sqrt(np.mean(pos**2))) if pos.size else 0.0,
        float(np.sqrt(np.mean(a**2))) if a.size else 0.0,
    )


def _lm(
    problem: CalibrationProblem,
    basis: np.ndarray,
    u0: np.ndarray,
    max_iter: int,
    tol: float,
    prior_weight: np.ndarray | None = None,
):
    """Levenberg–Marquardt in the coordinates w of ``basis`` (u = u0 + basis w); ``prior_weight`` (n,): the
    prior's rows ``prior_weight · u`` appended to the residuals (None: none). Returns the data residuals."""
    k = basis.shape[1]
    w = np.zeros(k)
    pw = None if prior_weight is None else np.asarray(prior_weight, float)

    def augmented(u: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray | None]:
        rd, jd = problem.residuals(u)
        if jd is None or pw is None:  # no prior: the data's rows alone
            return rd, jd, rd, jd
        return np.concatenate([rd, pw * u]), np.vstack([jd, np.diag(pw)]), rd, jd

    r, js, rd, jd = augmented(u0)
    assert js is not None
    cost = float(r @ r)
    lam = 1e-3
    it = 0
    converged = k == 0
    while it < max_iter and not converged:
        it += 1
        jw = js @ basis
        a = jw.T @ jw
        g = jw.T @ r
        diag = np.maximum(np.diag(a), 1e-12)
        improved = False
        for _ in range(30):
            try:
                step = -np.linalg.solve(a + lam * np.diag(diag), g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            try:
                r_new, js_new, rd_new, jd_new = augmented(u0 + basis @ (w + step))
            except KinematicsError:  # a trial step the mechanism cannot close: shorten it
                lam *= 10.0
                continue
            c_new = float(r_new @ r_new)
            if c_new <= cost and js_new is not None and np.all(np.isfinite(js_new)):  # NaN: a step too far
                improved = True
                w = w + step
                done = np.linalg.norm(step) <= tol * (1.0 + np.linalg.norm(w)) or cost - c_new <= tol * max(
                    cost, 1e-300
                )
                r, js, cost, rd, jd = r_new, js_new, c_new, rd_new, jd_new
                assert js is not None
                lam = max(lam / 10.0, 1e-12)
                converged = bool(done)
                break
            lam *= 10.0
        if not improved:
            converged = bool(np.linalg.norm(g) <= 1e-9 * max(1.0, math.sqrt(cost)))
            break
    return u0 + basis @ w, rd, jd, it, converged


def _information(jb: np.ndarray, basis: np.ndarray, prior_weight: np.ndarray | None) -> np.ndarray:
    """The information of the coordinates of ``basis`` (k, k): (JB)ᵀ JB, plus Bᵀ W² B with the prior's weights
    ``prior_weight`` (None: no prior)."""
    info = jb.T @ jb
    return info if prior_weight is None else info + basis.T @ (prior_weight[:, None] ** 2 * basis)


#: the variance of a value rounded to a whole count, in counts² (uniform within ± 0.5 count: the resolution
#: term of the GUM, u = q / √12)
ROUNDING_VARIANCE_COUNTS2 = 1.0 / 12.0


def _snap_ad(
    problem: CalibrationProblem,
    u: np.ndarray,
    min_singular: float,
    max_iter: int,
    tol: float,
    prior_weight: np.ndarray | None = None,
) -> tuple[np.ndarray, int, np.ndarray]:
    """Round the AD map to whole counts (the profile's integers) and refit the geometry with it fixed:
    (scaled deltas, iterations, the covariance the rounding adds to them in scaled units (n, n)).

    Each written count is off the fitted one by up to half a count (variance :data:`ROUNDING_VARIANCE_COUNTS2`);
    the AD parameters move by G δ (G = :meth:`ParameterSet.ad_count_jacobian`, δ the rounding errors) and the
    refit moves the rest to take up what it can, −B (J B)⁺ J_ad G δ (J the weighted scaled Jacobian, B the
    refit's basis), so the written values carry T G δ with T = [I; −B (J B)⁺ J_ad]: the covariance
    T G (I / 12) Gᵀ Tᵀ."""
    ps = problem.params
    n = len(ps)
    ad = np.array([name.startswith("ad_") for name in ps.names])
    if not ad.any():
        return u, 0, np.zeros((n, n))
    p = ps.nominal + ps.scale * u
    rounded = ps.values_of(profile_from_dict(ps.profile_dict(p, lag=False)))  # only its AD part is used
    u0 = u.copy()
    u0[ad] = (rounded[ad] - ps.nominal[ad]) / ps.scale[ad]
    _, js = problem.residuals(u0)
    assert js is not None
    _, sub, _ = identifiable_basis(js[:, ~ad], min_singular)
    basis = np.zeros((n, sub.shape[1]))
    basis[~ad] = sub
    g = ps.ad_count_jacobian(ps.nominal + ps.scale * u0) / ps.scale[:, None]  # scaled deltas per count
    t = np.zeros((n, int(ad.sum())))
    t[ad] = np.eye(int(ad.sum()))
    if basis.shape[1]:
        jb = js @ basis
        if prior_weight is None:
            t -= basis @ (np.linalg.pinv(jb) @ js[:, ad])
        else:  # the refit with the prior's rows: (JBᵀJB + Bᵀ W² B)⁻¹ (JB)ᵀ J_ad
            t -= basis @ np.linalg.solve(_information(jb, basis, prior_weight), jb.T @ js[:, ad])
    tg = t @ g[ad]
    cov_round = ROUNDING_VARIANCE_COUNTS2 * (tg @ tg.T)
    u1, _, _, iters, _ = _lm(problem, basis, u0, max_iter, tol, prior_weight)
    return u1, iters, cov_round


def solve_calibration(
    problem: CalibrationProblem,
    *,
    min_singular: float = 1.0,
    max_iter: int = 50,
    tol: float = 1e-12,
    snap_ad: bool = True,
    tape_prior: bool = True,
) -> CalibrationResult:
    """Calibrate: LM over the identifiable directions; singular values, σ̂, standard deviations (module).

    ``snap_ad``: round the calibrated AD map to whole counts (as the profile stores it) and refit the
    geometry with that map fixed, so the written profile is the best one the schema can hold; the named
    combinations are those of the continuous fit, the standard deviations its own plus what the rounding
    adds (each count off by up to half a count, carried through the refit: :func:`_snap_ad`), so they
    describe the values written. A fit that ends where
    the mechanism cannot close is a :class:`CalibrationError` naming the cause: measurements that do not fit
    the model (a wrong value, a unit slip: σ̂ large), or, where the fit agrees with the measurements, weakly
    identified directions (``min_singular`` small) that carried the parameters many tape sizes away.
    """
    if not (isinstance(min_singular, (int, float)) and math.isfinite(min_singular) and min_singular >= 0.0):
        raise CalibrationError(f"min_singular must be a number >= 0, got {min_singular!r}")
    if not (isinstance(max_iter, int) and 1 <= max_iter <= 1000):
        raise CalibrationError(f"max_iter must be an integer in [1, 1000], got {max_iter!r}")
    state: dict[str, object] = {}
    try:
        return _solve(problem, float(min_singular), max_iter, tol, snap_ad, state, bool(tape_prior))
    except (KinematicsError, _MapError) as exc:
        weak = None
        if "u" in state:
            weak = weak_fit_cause(
                problem.params.names,
                problem.params.scale,
                np.asarray(state["u"]),
                np.asarray(state["s"]),
                int(state["k"]),  # type: ignore[call-overload]
                float(min_singular),
                float(state["sigma_hat"]),  # type: ignore[arg-type]
                bool(state["converged"]),
                [q.unit for q in problem.params.parameters],
            )
        if weak is not None:
            raise CalibrationError(f"the fit ends where the profile cannot hold it ({exc}): {weak}") from None
        raise CalibrationError(
            f"the fit ends where the mechanism cannot close ({exc}): the measurements do not fit the model; "
            "check for a wrong value, a unit slip (mm or degrees in a column of m or rad), or a sign or left/right "
            "slip (x measured to the other side, the L and R points swapped)"
        ) from None


class _MapError(CalibrationError):
    """The AD map the fit reached cannot be written (snapping it to whole counts); its text says why (a
    CalibrationError: every exception of the planner derives from HitchError)."""


def weak_fit_cause(
    names: Sequence[str],
    scale: np.ndarray,
    u: np.ndarray,
    singular_values: np.ndarray,
    identified: int,
    min_singular: float,
    sigma_hat: float,
    converged: bool,
    units: Sequence[str] | None = None,
) -> str | None:
    """Why a fit whose parameters (scaled deltas ``u``) cannot make a usable profile failed, when the
    measurements are not to blame (σ̂ ≤ :data:`FIT_SIGMA_HAT`): the fit did not converge, or directions the
    poses identify only weakly carried a parameter far; None when σ̂ says the measurements do not fit (the
    caller says so). ``--min-singular 0.01`` ended in "the measurements do not fit the model (… sigma-hat
    1.31)", a good fit (a commissioning trial)."""
    if not math.isfinite(sigma_hat) or sigma_hat > FIT_SIGMA_HAT:
        return None
    i = int(np.argmax(np.abs(u))) if u.size else 0
    weakest = float(singular_values[identified - 1]) if identified > 0 else math.nan
    unit = "" if units is None or units[i] == "1" else f" {units[i]}"
    moved = (
        f"{names[i]} moved {abs(float(u[i])):.1f} tape sizes ({float(u[i] * scale[i]):+.4g}{unit})" if u.size else ""
    )
    if not converged:
        head = f"the fit did not converge (sigma-hat {sigma_hat:.3g} so far); {moved}"
    else:
        head = f"the fit agrees with the measurements (sigma-hat {sigma_hat:.3g}), but {moved}"
    return (
        f"{head} along directions the poses identify only weakly (the weakest identified singular value "
        f"{weakest:.3g}, min_singular {min_singular:g}{', below the default 1' if min_singular < 1.0 else ''}): "
        "such a direction moves the fit by less than a σ per tape size, so the noise carries it far; raise "
        "--min-singular (default 1) to keep them at nominal, or measure more poses"
    )


def _solve(
    problem: CalibrationProblem,
    min_singular: float,
    max_iter: int,
    tol: float,
    snap_ad: bool,
    state: dict[str, object] | None = None,
    tape_prior: bool = True,
) -> CalibrationResult:
    """:func:`solve_calibration` (its arguments checked) without its translation of a mechanism that cannot close;
    ``state`` receives the continuous fit (u, s, k, sigma_hat, converged) for that translation."""
    t0 = time.perf_counter()
    state = {} if state is None else state
    ps = problem.params
    n = len(ps)
    u = np.zeros(n)
    r0, js0 = problem.residuals(u)
    assert js0 is not None
    if not (np.all(np.isfinite(r0)) and np.all(np.isfinite(js0))):
        raise CalibrationError(
            "measurements: the nominal model cannot evaluate every row (a reading the mechanism cannot reach)"
        )
    nominal_rms = _rms(problem, r0)
    _, basis, _ = identifiable_basis(js0, min_singular)
    u, r, js, iters, converged = _lm(problem, basis, u, max_iter, tol)
    s, basis2, unid = identifiable_basis(js, min_singular)
    if basis2.shape[1] != basis.shape[1]:  # the split moved at the solution: polish in the new subspace
        u_proj = basis2 @ (basis2.T @ u)
        u, r, js, more, converged = _lm(problem, basis2, u_proj, max_iter, tol)
        iters += more
        s, basis2, unid = identifiable_basis(js, min_singular)
    k = basis2.shape[1]
    m = r.size
    if m <= k:
        raise CalibrationError(
            f"measurements: {_count(m, 'measured value')} for {_count(k, 'parameter direction')} the poses can "
            f"see: a fit needs more values than directions (at least {k + 1}, one over to estimate the residual); "
            "measure more poses"
        )
    distinct = problem.data.n_distinct_observations
    if distinct <= k:  # repeats of the same readings (a copied row) add values but no direction
        raise CalibrationError(
            f"measurements: {_count(problem.data.n_rows, 'row')} hold {_count(problem.data.n_poses, 'distinct pose')} "
            f"(rows with the same readings or label count once) with {_count(distinct, 'measured value')} for "
            f"{_count(k, 'parameter direction')} the poses can see: a fit needs more values than directions "
            f"(at least {k + 1}); measure more poses (a copied row is not a new pose)"
        )
    sigma_hat = math.sqrt(float(r @ r) / (m - k))
    state.update(u=u.copy(), s=s, k=k, sigma_hat=sigma_hat, converged=bool(converged))
    u_least_squares = u.copy()
    pw = None
    if tape_prior and k:
        pw = np.full(n, sigma_hat / PRIOR_SIGMA_SCALED)
        pw[problem.params.lag_index] = 0.0  # the lag's band is not a tape error around a nominal
        # from the least-squares solution and from the nominal, the lower cost |r|² + |W u|² kept: where the least
        # squares went far along weak directions (a small min_singular; a polish whose direction the final split
        # drops: outside basis2, the fit from there cannot move back) the fit from its solution stopped 62 tape
        # sizes out, "converged", every σ within the tape's (a review: min_singular 0.01; 5.4 at 0.1)
        runs = [_lm(problem, basis2, start, max_iter, tol, pw) for start in (u, np.zeros(n))]
        iters += sum(run[3] for run in runs)
        u, r, js, _, converged = min(runs, key=lambda run: float(run[1] @ run[1]) + float(np.sum((pw * run[0]) ** 2)))
    cov_w = sigma_hat**2 * np.linalg.inv(_information(js @ basis2, basis2, pw)) if k else np.zeros((0, 0))
    cov_u = basis2 @ cov_w @ basis2.T
    std = ps.scale * np.sqrt(np.maximum(np.diag(cov_u), 0.0))
    words = tuple(
        f"{ps.describe(unid[:, i])} (singular value {sv:.3g})"
        for i, sv in zip(range(unid.shape[1]), s[k:], strict=False)
    )
    if snap_ad:
        try:
            u, more, cov_round = _snap_ad(problem, u, min_singular, max_iter, tol, pw)
        except CalibrationError as exc:  # the AD map left the counts: not the measurements' fault alone
            raise _MapError(str(exc)) from None
        iters += more
        cov_u = cov_u + cov_round
        std = ps.scale * np.sqrt(np.maximum(np.diag(cov_u), 0.0))
        r, _ = problem.residuals(u, jacobian=False)
    rms = _rms(problem, r)
    return CalibrationResult(
        names=ps.names,
        nominal=ps.nominal,
        values=ps.nominal + ps.scale * u,
        std=std,
        scale=ps.scale,
        singular_values=s,
        identified=k,
        unidentifiable=words,
        basis=basis2,
        covariance_scaled=cov_u,
        residual_rms_position_m=rms[0],
        residual_rms_angle_rad=rms[1],
        residual_rms_nominal_position_m=nominal_rms[0],
        residual_rms_nominal_angle_rad=nominal_rms[1],
        residual_sigma=sigma_hat,
        n_poses=problem.data.n_poses,
        n_observations=m,
        iterations=iters,
        converged=bool(converged),
        duration_s=time.perf_counter() - t0,
        min_singular=min_singular,
        tape_prior=pw is not None,
        values_least_squares=ps.nominal + ps.scale * u_least_squares,
    )


def check_residual_dof(result: CalibrationResult, data: MeasurementSet) -> None:
    """:class:`CalibrationError` when the fit's residual degrees of freedom (values − identified directions)
    are fewer than its identified directions: σ̂ from so few spare values cannot check the fit (2 poses: 8
    values, 7 directions, σ̂ 0.40 from one spare value, and the profile was written: a trial); likewise when the
    distinct poses (a pose measured from both sides once) hold fewer than twice the identified directions' values
    (one pose from both sides, 8 values for 4 directions, was written: a commissioning trial). The message
    names how many values and poses a fit needs."""
    m, k = result.n_observations, result.identified
    per = max(1, int(np.max(data.mask.sum(axis=1))))
    if m - k >= k:
        poses = _poses_by_label(data)  # a pose measured from both sides (its label on both) counts once
        if poses * per >= 2 * k:
            return
        raise CalibrationError(
            f"measurements: {_count(data.n_rows, 'row')} hold {_count(poses, 'distinct pose')} (a pose measured from "
            f"both sides counts once: its two rows tell the pin play's lag, not more geometry) with {per} values "
            f"each for {_count(k, 'identified parameter direction')}: a fit needs at least {2 * k} values of "
            f"distinct poses, at least {math.ceil(2 * k / per)} poses; measure more poses"
        )
    raise CalibrationError(
        f"measurements: {_count(result.n_poses, 'pose')} with {_count(m, 'measured value')} for "
        f"{_count(k, 'identified parameter direction')} leave {m - k} to check the fit (sigma-hat), fewer than "
        f"the directions: a fit needs at least {2 * k} values, at least {math.ceil(2 * k / per)} poses of "
        f"{per} values each (more poses identify more directions and need more still: plan-poses plans 20); "
        "measure more poses"
    )


def _poses_by_label(data: MeasurementSet) -> int:
    """Distinct poses for :func:`check_residual_dof`: the distinct labels of the rows with a side (a pose measured
    from below and from above has its label on both; its readings differ by the lag), plus the distinct readings
    of the rows without one. Not :attr:`MeasurementSet.n_poses` (the larger side's count): 8 poses measured once
    each, from alternating sides, counted 4 and were refused (a review)."""
    side = data.side_vector
    by_readings = data.n_poses
    if tuple(data.labels) == tuple(str(n) for n in data.row_numbers):  # no pose column: the readings alone (a pose's
        return by_readings  # two rows were 2 poses by their row numbers, a second review)
    sided = {data.labels[i] for i in np.flatnonzero(side != 0).tolist()}
    rows = side == 0
    unsided = int(np.unique(data.readings[rows], axis=0).shape[0]) if np.any(rows) else 0
    return max(len(sided) + unsided, by_readings)  # one label for several poses: their readings tell them apart


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def largest_residuals(
    problem: CalibrationProblem, result: CalibrationResult | np.ndarray, count: int = 3
) -> list[tuple[int, str, str, float]]:
    """The ``count`` data rows that fit worst, worst first: ``(row, label, column, residual)`` with ``row``
    counted from 1 as the measurement file's data rows, the column of the row's largest residual and that
    residual (measured − model) in units of its σ. The model at the calibration ``result``, or at parameter
    values (an array: a profile's own, ``calibrate check``). With σ̂ far above 1 the worst row is where to look
    for a wrong value or a unit slip (an engineer's report: the warning named no row)."""
    values = result.values if isinstance(result, CalibrationResult) else result
    y, _ = problem.model.batch(
        problem.data.readings, values, jacobian=False, seeds=problem.seeds, sides=problem.data.side_vector
    )
    r = np.where(problem.data.mask, (np.nan_to_num(problem.data.values) - y) / problem.sigma, 0.0)
    worst = np.argmax(np.abs(r), axis=1)
    size = np.abs(r[np.arange(len(r)), worst])
    rows = np.argsort(-size, kind="stable")[: max(0, int(count))]
    numbers = problem.data.row_numbers  # the file's rows (its exact copies dropped)
    return [
        (numbers[int(k)], problem.data.labels[k], MEASURED_COLUMNS[int(worst[k])], float(r[k, worst[k]])) for k in rows
    ]


#: a standardized residual (measured − calibrated, in units of the σ given) beyond which a row is named
OUTLIER_SIGMA = 5.0


def outlying_rows(
    problem: CalibrationProblem, result: CalibrationResult, limit: float = OUTLIER_SIGMA
) -> list[tuple[int, str, str, float]]:
    """The rows (as :func:`largest_residuals`) whose largest residual exceeds ``limit`` σ, worst first: one wrong
    cell (a +10 mm z, 8.7 σ at σ = 1 mm) leaves σ̂ near 1 among 80 values and was written without a word (a
    trial); noise of the σ given reaches 5 σ about once in 3.5 million values."""
    worst = largest_residuals(problem, result, count=problem.data.n_rows)
    return [w for w in worst if abs(w[3]) > limit]
