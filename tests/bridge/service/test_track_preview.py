"""The streaming client's row estimator and preview (bridge.service.track_loop): the Kalman row
estimator against the twin's true row, the preview plan against its bounds (finite differences of
the path itself), the lead from the follower's limits, and a short closed loop against the truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bridge.service.track_loop import (
    LoopSettings,
    PreviewPlanner,
    RowKalman,
    RowModel,
    TrackLoopError,
    _AlphaBeta,
    follower_lead_s,
    path_state,
    run_track_loop,
)
from bridge.sim.scenario import scenario_from_dict
from bridge.sim.terrain import RowSignal

V = 4 / 3.6


def _row(ahead: float = 0.0, noise: float = 0.005) -> RowSignal:
    return RowSignal(
        rms_m=0.02, wavelength_min_m=1.2, wavelength_max_m=30.0, noise_rms_m=noise, seed=2024, camera_ahead_m=ahead
    )


def test_row_model_from_the_stated_spectrum_matches_the_rows_rms_and_rms_slope():
    row = _row()
    m = RowModel.from_row(row)
    s = np.linspace(0.0, 2000.0, 200001)
    y = np.array([row.true_offset_m(float(x)) for x in s[::10]])
    slope = np.gradient(y, s[::10])
    assert m.rms_m == 0.02 and m.noise_rms_m == 0.005
    # the model's rms(y') = ω·rms(y) matches the row's own (numerical) slope over 2 km
    assert m.omega_rad_m * np.sqrt(np.mean(y**2)) == pytest.approx(np.sqrt(np.mean(slope**2)), rel=0.1)
    # its stationary variance is the stated RMS: F P F' + Q = P for the stationary P
    f, q = m.transition(0.3)
    p = np.diag([m.rms_m**2, (m.omega_rad_m * m.rms_m) ** 2])
    assert f @ p @ f.T + q == pytest.approx(p, rel=1e-6, abs=1e-12)
    with pytest.raises(TrackLoopError, match="omega_rad_m"):
        RowModel(0.02, 0.0, 0.005)


def _camera_run(row: RowSignal, seconds: float, query_ahead_s: float = 0.0):
    """Feed the camera's samples (10 Hz) keyed by distance; errors of the estimate under the implement."""
    kf, ab = RowKalman(RowModel.from_row(row)), _AlphaBeta(0.35, 0.06)
    e_kf, e_ab, e_raw = [], [], []
    last = None
    for n in range(int(seconds / 0.02)):
        t = n * 0.02
        k = row.sample_index(t)
        if k != last:
            last, tk = k, k / row.rate_hz
            z = row.true_offset_m(V * tk + row.camera_ahead_m) + row.noise_m(k)
            kf.add(z, V * tk + row.camera_ahead_m)
            ab.update(z, tk)
        if t < 5.0:
            continue
        target = V * (t + query_ahead_s)
        est = kf.at(target)
        assert est is not None
        e_kf.append(est[0] - row.true_offset_m(target))
        e_ab.append(ab.at(t)[0] - row.true_offset_m(V * t))
        e_raw.append(z - row.true_offset_m(V * t))
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    return rms(e_kf), rms(e_ab), rms(e_raw)


def test_kalman_row_estimate_is_closer_to_the_true_row_than_the_alpha_beta_filter():
    kf, ab, raw = _camera_run(_row(), 40.0)
    assert kf < 0.7 * ab, (kf, ab)
    assert kf < raw, (kf, raw)


def test_with_a_camera_ahead_the_row_under_the_implement_is_smoothed_below_the_camera_noise():
    kf, _, _ = _camera_run(_row(ahead=3.9), 40.0)
    assert kf < 0.005, kf  # the camera's own noise is 5 mm RMS; both sides of the point were seen
    # an empty filter has no estimate; a sample behind the newest is ignored
    f = RowKalman(RowModel.from_row(_row()))
    assert f.at(1.0) is None
    f.add(0.01, 2.0)
    f.add(0.5, 1.0)
    assert len(f) == 1


def test_preview_plan_keeps_within_its_bounds_and_continues_the_path_sent():
    row = _row(noise=0.0)
    v_max, a_max, j_max, dt = 0.044, 0.145, 0.96, 0.02
    pl = PreviewPlanner(v_max, a_max, j_max, dt)
    sent: list[float] = []
    prev = np.zeros(0)
    n = 175
    for c in range(0, 300, 5):  # re-planned at 10 Hz, as the loop does
        t0 = c * dt
        ref = np.array([row.true_offset_m(V * (t0 + k * dt)) for k in range(n)])
        path = pl.plan(t0, ref)
        if sent:
            # the first three samples are the previous plan's: position, velocity, acceleration continue
            assert path[:3] == pytest.approx(prev[5:8], abs=1e-12)
        prev = path
        sent.extend(path[:5])
    x = np.array(sent)
    slack = 1.01  # the QP's tolerance: 1e-3 of each bound
    assert np.max(np.abs(np.diff(x))) / dt <= v_max * slack
    assert np.max(np.abs(np.diff(x, 2))) / dt**2 <= a_max * slack
    assert np.max(np.abs(np.diff(x, 3))) / dt**3 <= j_max * slack
    assert pl.failures == 0
    with pytest.raises(TrackLoopError, match="8 finite samples"):
        pl.plan(0.0, np.zeros(5))


def test_path_state_is_the_b_spline_of_the_samples_consistent_from_one_sample_to_the_next():
    """Invariants of the uniform cubic B-spline on the samples: each sample's state extrapolated over one
    step with its jerk is the next sample's state (the stream the follower meets exactly), the jerk is
    the third difference, and a constant / linear / quadratic path is reproduced exactly."""
    rng = np.random.default_rng(7)
    dt = 0.02
    x = np.cumsum(np.cumsum(np.cumsum(rng.normal(0.0, 1e-6, 60))))
    for i in range(1, 56):
        p, v, a, j = path_state(x, i, dt)
        p1, v1, a1, _ = path_state(x, i + 1, dt)
        assert p + v * dt + a * dt**2 / 2 + j * dt**3 / 6 == pytest.approx(p1, abs=1e-15)
        assert v + a * dt + j * dt**2 / 2 == pytest.approx(v1, abs=1e-13)
        assert a + j * dt == pytest.approx(a1, abs=1e-11)
        assert j == pytest.approx((x[i + 2] - 3 * x[i + 1] + 3 * x[i] - x[i - 1]) / dt**3)
    t = dt * np.arange(10)
    p, v, a, j = path_state(0.1 + 0.2 * t + 0.3 * t**2, 4, dt)
    # a quadratic's B-spline is the quadratic shifted by a·dt²/6 (the smoothing (x₋ + 4x₀ + x₊)/6)
    assert (p, v, a, j) == pytest.approx(
        (0.1 + 0.2 * t[4] + 0.3 * t[4] ** 2 + 0.6 * dt**2 / 6, 0.2 + 0.6 * t[4], 0.6, 0.0), abs=1e-9
    )
    with pytest.raises(TrackLoopError, match="4 samples"):
        path_state(np.zeros(3), 1, dt)


def test_follower_lead_is_two_cycles_plus_the_rise_time_to_full_speed():
    assert follower_lead_s(0.05, 0.2, 1.0, 0.02) == pytest.approx(0.04 + 0.25 + 0.2)
    with pytest.raises(TrackLoopError, match="acceleration"):
        follower_lead_s(0.05, 0.0, 1.0, 0.02)


def test_bad_row_settings_name_the_field():
    with pytest.raises(TrackLoopError, match="row_estimator"):
        LoopSettings(row_estimator="median")
    with pytest.raises(TrackLoopError, match="row_setpoint"):
        LoopSettings(row_setpoint="later")
    with pytest.raises(TrackLoopError, match="kalman"):
        LoopSettings(row_setpoint="plan")  # the α-β filter has no row model to plan on
    with pytest.raises(TrackLoopError, match="lead_s"):
        LoopSettings(lead_s=math.inf)


def _guidance(ahead: float):
    return scenario_from_dict(
        {
            "schema_version": 1,
            "name": "row-preview",
            "duration_s": 16.0,
            "speed": {"constant_m_s": V},
            "signals": {
                "row_offset_rms_m": 0.02,
                "row_wavelength_min_m": 1.2,
                "row_wavelength_max_m": 30.0,
                "row_noise_rms_m": 0.005,
                "row_camera_ahead_m": ahead,
                "seed": 2024,
            },
        }
    )


def test_a_preview_plan_follows_the_true_row_closer_than_the_camera_under_the_implement(model):
    before = run_track_loop(model, _guidance(0.0), LoopSettings(strategy="track"))
    plan = run_track_loop(
        model, _guidance(3.9), LoopSettings(strategy="track", row_estimator="kalman", row_setpoint="plan")
    )
    # the error is against the twin's true row under the implement and the simulated pistons' x
    assert np.allclose(plan.error, plan.truth[:, 0] - plan.row)
    assert plan.figures.rms < 0.6 * before.figures.rms, (plan.figures, before.figures)
    for r in (before, plan):
        assert r.counts["references_outside_strokes"] == 0 and r.counts["refused"] == 0
        assert r.counts["outside_workspace"] == 0 and r.counts["setpoints_rejected"] == 0 and not r.faults
