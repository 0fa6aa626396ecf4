"""The pose accuracy a calibration predicts (``planner.calibration.predicted``), against independent truth:
the quantile of a Gaussian mixture against its closed form and against sampling; the linear propagation against
Monte Carlo of the nonlinear model; and the predicted p95 against the errors of noisy fits measured against the
truth they were fitted to (the "no quantisation" evaluation of ``bench/calibration_bench.py``).
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest

from planner.calibration import (
    CalibrationError,
    MeasurementSet,
    ParametricModel,
    build_calibration_problem,
    calibrated_covariance,
    candidate_poses,
    plan_poses,
    predict_accuracy,
    solve_calibration,
    tape_covariance,
)
from planner.calibration.design import measured_rows
from planner.calibration.predicted import mixture_quantile
from planner.profiles.hitch import load_profile

SIGMA_M, SIGMA_RAD = 1e-3, 1e-3  # the total station of the issue


@cache
def _model() -> ParametricModel:
    return ParametricModel(load_profile("thesis-t132"), rigid_span=True)


@cache
def _planned() -> np.ndarray:
    return plan_poses(_model(), 20).actuators


@cache
def _evaluation() -> np.ndarray:
    return candidate_poses(_model(), 200, seed=77, random_only=True)[1]


def _noisy_fit(seed: int):
    """A tape-perturbed truth (each parameter uniform within ± its tape size), the 20 planned poses measured by
    the model at the truth with the station's Gaussian noise, and the fit."""
    model = _model()
    ps = model.params
    rng = np.random.default_rng(seed)
    p_true = ps.nominal + ps.scale * rng.uniform(-1.0, 1.0, len(ps))
    y, _ = model.batch(_planned(), p_true, jacobian=False)
    y = y + rng.normal(size=y.shape) * SIGMA_M  # 1 mm and 1 mrad: one σ for every row
    mask = np.zeros_like(y, dtype=bool)
    mask[:, measured_rows(points=False)] = True
    data = MeasurementSet(_planned(), np.where(mask, y, np.nan), mask, tuple(str(i) for i in range(len(y))))
    problem = build_calibration_problem(model, data, sigma_position_m=SIGMA_M, sigma_angle_rad=SIGMA_RAD)
    return p_true, solve_calibration(problem, snap_ad=False)


def test_the_mixture_quantile_of_equal_sigmas_is_the_gaussian_s_and_of_unequal_ones_what_sampling_gives():
    z95 = 1.959963984540054  # Φ⁻¹(0.975): P(|N(0, 1)| ≤ z) = 0.95
    assert mixture_quantile(np.full(7, 2e-3), 0.95) == pytest.approx(z95 * 2e-3, rel=1e-9)
    sig = np.array([0.5e-3, 1e-3, 3e-3, 0.0])
    t = mixture_quantile(sig, 0.95)
    assert np.mean([math.erf(t / (s * math.sqrt(2))) if s > 0 else 1.0 for s in sig]) == pytest.approx(0.95, abs=1e-9)
    draws = np.abs(np.random.default_rng(1).normal(size=(200_000, sig.size)) * sig).reshape(-1)
    assert t == pytest.approx(np.quantile(draws, 0.95), rel=0.01)
    assert mixture_quantile(np.zeros(3), 0.95) == 0.0
    for bad in (np.array([]), np.array([1.0, np.nan]), np.array([-1.0])):
        with pytest.raises(CalibrationError, match="sigmas"):
            mixture_quantile(bad, 0.95)


def test_the_linear_prediction_matches_monte_carlo_of_the_nonlinear_model():
    """Parameter errors drawn from a fit's covariance (shrunk to a tenth in σ: the first-order term alone),
    pushed through the exact forward map at fixed readings: the spread of the pose equals the predicted σ (a
    check of J and of J Σ Jᵀ, independent of the fit). At the full covariance z's spread is 1.6 × the linear one
    for Gaussian draws: the fit's weakest direction moves z with its square (docs/commissioning.md); the fits
    themselves reach what is predicted (the next test)."""
    model = _model()
    _, res = _noisy_fit(3)
    cov = 0.01 * calibrated_covariance(res)
    readings = _evaluation()[:6]
    pred = predict_accuracy(model, res.values, cov, readings)
    rng = np.random.default_rng(11)
    draws = rng.multivariate_normal(np.zeros(len(res.names)), cov, size=1500)
    base, _ = model.batch(readings, res.values, jacobian=False)
    errs = []
    for d in draws:
        y, _ = model.batch(readings, res.values + model.params.scale * d, jacobian=False)
        errs.append((y - base)[:, [0, 2, 3, 4]])
    empirical = np.std(np.array(errs), axis=0)  # (6, 4)
    assert np.allclose(empirical, pred.sigma, rtol=0.08), (empirical / pred.sigma).round(3)


def test_the_predicted_p95_is_what_noisy_fits_reach_against_their_truth():
    """Eight tape-perturbed truths fitted from noisy station data: over their 8 × 200 workspace poses the errors
    of the calibrated profiles against the truth have the p95 the fits predicted (pooled, per DOF, within 25 %);
    the nominal profile's prediction is the tape's, many times larger."""
    model = _model()
    ev = _evaluation()
    errors, sigmas = [], []
    for seed in range(8):
        p_true, res = _noisy_fit(seed)
        sigmas.append(predict_accuracy(model, res.values, calibrated_covariance(res), ev).sigma)
        truth, _ = model.batch(ev, p_true, jacobian=False)
        fitted, _ = model.batch(ev, res.values, jacobian=False)
        errors.append((truth - fitted)[:, [0, 2, 3, 4]])
    achieved = np.quantile(np.abs(np.concatenate(errors)), 0.95, axis=0)
    pooled = np.concatenate(sigmas)
    predicted = np.array([mixture_quantile(pooled[:, k], 0.95) for k in range(4)])
    assert np.allclose(achieved, predicted, rtol=0.25), (1e3 * achieved, 1e3 * predicted)
    tape = predict_accuracy(model, model.params.nominal, tape_covariance(len(model.params)), ev).p95
    assert np.all(tape > 5.0 * predicted), (1e3 * tape, 1e3 * predicted)


def test_a_covariance_of_the_wrong_shape_is_refused():
    with pytest.raises(CalibrationError, match="covariance"):
        predict_accuracy(_model(), _model().params.nominal, np.eye(3), _evaluation()[:2])


def test_a_fitted_lag_s_error_shows_on_the_side_gotos_end_from():
    """A review: the lag was evaluated at side 0, so its own σ never reached the prediction although every goto
    ends from the final approach's side. Closed form: with only the lag uncertain (σ of a tape size each), a
    pose's error in each DOF the lag acts on is that σ times the lag's scale, from either side; none at side 0."""
    from planner.calibration import ParameterSet
    from planner.profiles.hitch import profile_from_dict

    data = load_profile("thesis-t132").model_dump()
    data["motion"]["final_approach"] = {"x": 0.0025, "z": 0.004, "roll": 0.005, "pitch": 0.007}
    prof = profile_from_dict(data)
    model = ParametricModel(prof, params=ParameterSet.from_profile(prof, include_lag=True))
    ps = model.params
    lag = ps.lag_index
    cov = np.zeros((len(ps), len(ps)))
    cov[lag, lag] = 0.3**2
    readings = _evaluation()[:5]
    for side in (-1.0, 1.0):
        got = predict_accuracy(model, ps.nominal, cov, readings, side=side).sigma
        want = np.zeros(4)
        want[list(ps.lag_dofs)] = 0.3 * ps.scale[lag]
        assert np.allclose(got, want[None, :], rtol=1e-9, atol=1e-15), (got, want)
    assert np.all(predict_accuracy(model, ps.nominal, cov, readings).sigma == 0.0)
    with pytest.raises(CalibrationError, match="side"):
        predict_accuracy(model, ps.nominal, cov, readings, side=0.5)
