"""The terrain-following client's ground profile (bridge.service.ground_preview) against the twin's truth: the
ground under the implement it predicts ahead (in travelled distance) is what the twin computes when the
implement gets there, for any speed profile; the body's pitch and heave are accounted for; bad geometry is
refused with the field and its range."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bridge.service.ground_preview import GroundPreviewError, GroundPreviewGeometry, GroundProfileEstimator
from bridge.sim.terrain import LookAheadGroundSensor, SineGround, SpeedProfile, TerrainTwin, TractorGeometry, Undulation

L, BEHIND, AHEAD, MOUNT = 2.7, 1.2, 4.9, 0.8
GROUND = SineGround(undulations=(Undulation(0.03, 7.0), Undulation(0.02, 19.0, 0.5)))


def twin(speed: SpeedProfile, noise: float = 0.0) -> TerrainTwin:
    return TerrainTwin(
        ground=GROUND,
        speed=speed,
        tractor=TractorGeometry(L, 1.8, "rigid"),
        implement_behind_m=BEHIND,
        ground_sensor=LookAheadGroundSensor(ahead_m=AHEAD, mount_height_m=MOUNT, noise_rms_m=noise, seed=3),
    )


def geometry(noise: float = 0.003) -> GroundPreviewGeometry:
    return GroundPreviewGeometry(L, BEHIND, AHEAD, MOUNT, sensor_noise_m=noise)


def feed(est: GroundProfileEstimator, tw: TerrainTwin, t_end: float, *, implement_noise: float = 0.0) -> None:
    """The twin's sensors every 20 ms up to ``t_end``, each keyed by the distance travelled then."""
    rng = np.random.default_rng(1)
    for t in np.arange(0.0, t_end + 1e-9, 0.02):
        t = float(t)
        sigma = tw.distance_m(t)
        pitch = tw.attitude(t).pitch_rad
        est.add_pitch(sigma, pitch)
        est.add_ahead(sigma, tw.ground_ahead_distance_m(t), pitch)
        est.add_implement(sigma, tw.implement_ground_z(t) + rng.normal(0.0, implement_noise), pitch)


def time_at(tw: TerrainTwin, sigma: float) -> float:
    """When the rear axle reaches ``sigma`` (bisection on the twin's distance)."""
    lo, hi = 0.0, 1000.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if tw.distance_m(mid) < sigma else (lo, mid)
    return 0.5 * (lo + hi)


def preview_errors(est: GroundProfileEstimator, tw: TerrainTwin, sigma_now: float) -> np.ndarray:
    """Predicted minus true ground under the implement, from now to where the front wheels' ground is seen."""
    horizon = AHEAD - BEHIND - L  # a − L: the body's future pitch is known that far ahead of the rear axle
    sig = np.linspace(sigma_now, sigma_now + horizon, 21)
    truth = np.array([tw.implement_ground_z(time_at(tw, float(s))) for s in sig])
    return est.implement_ground(sig) - truth


def test_the_ground_under_the_implement_is_predicted_ahead_exactly_without_noise():
    tw = twin(SpeedProfile.constant(8 / 3.6))
    est = GroundProfileEstimator(geometry(0.0))
    feed(est, tw, 12.0)
    sigma_now = tw.distance_m(12.0)
    assert est.solve(sigma_now)
    err = preview_errors(est, tw, sigma_now)
    span = np.ptp([tw.implement_ground_z(float(t)) for t in np.linspace(0, 12, 200)])
    assert span > 0.06  # the ground under the implement moves by more than 60 mm
    assert np.max(np.abs(err)) < 2e-4, err


def test_the_buffer_is_in_distance_any_speed_profile_gives_the_same_ground():
    steady = twin(SpeedProfile.constant(2.0))
    varying = twin(SpeedProfile((0.0, 4.0, 8.0), (0.5, 3.0, 1.5)))  # accelerating, then slowing down
    sigma_now = 22.0
    out = []
    for tw in (steady, varying):
        est = GroundProfileEstimator(geometry(0.0))
        feed(est, tw, time_at(tw, sigma_now))
        assert est.solve(sigma_now)
        out.append(est.implement_ground(np.linspace(sigma_now, sigma_now + 1.0, 11)))
        assert np.max(np.abs(preview_errors(est, tw, sigma_now))) < 2e-4
    assert np.max(np.abs(out[0] - out[1])) < 2e-4


def test_the_body_frame_matters_reading_the_sensor_as_the_future_ground_would_not_do():
    """The naive preview (the look-ahead sensor's ground above today's plane, taken as the ground under the
    implement when it gets there) errs by centimetres: the tractor pitches and heaves meanwhile."""
    tw = twin(SpeedProfile.constant(8 / 3.6))
    v = 8 / 3.6
    naive = []
    for t in np.arange(3.0, 15.0, 0.1):
        arrive = t + AHEAD / v
        naive.append((MOUNT - tw.ground_ahead_distance_m(float(t))) - tw.implement_ground_z(float(arrive)))
    assert np.sqrt(np.mean(np.square(naive))) > 0.01


def test_with_sensor_noise_the_preview_is_better_than_one_reading():
    tw = twin(SpeedProfile.constant(8 / 3.6), noise=0.003)
    est = GroundProfileEstimator(geometry(0.003))
    feed(est, tw, 15.0, implement_noise=0.001)
    sigma_now = tw.distance_m(15.0)
    assert est.solve(sigma_now)
    err = preview_errors(est, tw, sigma_now)
    assert np.sqrt(np.mean(err**2)) < 2.5e-3, err


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"wheelbase_m": 0.0}, "wheelbase_m"),
        ({"implement_behind_m": -0.5}, "implement_behind_m"),
        ({"sensor_ahead_m": 1.0}, "sensor_ahead_m"),  # behind the rear axle: no preview
        ({"sensor_ahead_m": 25.0}, "sensor_ahead_m"),
        ({"mount_height_m": math.inf}, "mount_height_m"),
        ({"sensor_noise_m": 1.0}, "sensor_noise_m"),
    ],
)
def test_bad_geometry_is_refused_with_the_field_and_range(kw, field):
    args = {"wheelbase_m": L, "implement_behind_m": BEHIND, "sensor_ahead_m": AHEAD, "mount_height_m": MOUNT} | kw
    with pytest.raises(GroundPreviewError, match=field) as exc:
        GroundPreviewGeometry(**args)
    assert "[" in str(exc.value) or "(" in str(exc.value)


def test_estimator_settings_and_samples_are_checked():
    with pytest.raises(GroundPreviewError, match="step_m"):
        GroundProfileEstimator(geometry(), step_m=0.0)
    est = GroundProfileEstimator(geometry())
    assert not est.solve(0.0)
    with pytest.raises(GroundPreviewError, match="solve first"):
        est.implement_ground(0.0)
    with pytest.raises(GroundPreviewError, match="finite"):
        est.add_ahead(1.0, math.nan, 0.0)
