"""The twin's preview ground sensor (bridge.sim.preview_sensor) against geometry worked out here: a bump
under the sensor with both axles on flat ground, a grade (the tractor pitches with it: nothing above the
contact plane), a ground that lifts the front axle, and the noise's statistics."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.sim.preview_sensor import PreviewSensor, PreviewSensorConfig, PreviewSensorError
from bridge.sim.terrain import SampledGround, SpeedProfile, TerrainTwin, TractorGeometry

QUIET = PreviewSensorConfig(ahead_of_front_axle_m=1.0, height_m=0.8, noise_rms_m=0.0, resolution_m=0.0)


def twin(distances, heights, speed=0.0):
    return TerrainTwin(
        ground=SampledGround(tuple(distances), tuple(heights)),
        speed=SpeedProfile.constant(speed),
        tractor=TractorGeometry(2.7, 1.8),
    )


def test_a_bump_under_the_sensor_with_the_axles_on_flat_ground():
    """Rear axle at 0, front axle at 2.7, sensor at 3.7 m: a 60 mm plateau from 3.5 to 3.9 m lies only
    under the sensor, so it reads 0.8 - 0.06 m."""
    s = PreviewSensor(twin([0.0, 3.4, 3.5, 3.9, 4.0, 10.0], [0.0, 0.0, 0.06, 0.06, 0.0, 0.0]), QUIET)
    assert s.ahead_of_rear_axle_m == pytest.approx(3.7)
    assert s.read(0.0) == pytest.approx(0.8 - 0.06, abs=1e-12)


def test_a_grade_gives_nothing_above_the_contact_plane_and_a_lifted_front_axle_tilts_the_plane():
    grade = PreviewSensor(twin([-10.0, 20.0], [-0.5, 1.0]), QUIET)  # 5 % grade
    assert grade.read(0.0) == pytest.approx(0.8, abs=1e-12)
    # a 50 mm block under the front axle only (2.6 .. 2.8 m): the plane rises 50 mm over 2.7 m, so 1 m
    # further on it is 50·3.7/2.7 mm above the flat ground where the sensor looks
    front = PreviewSensor(twin([0.0, 2.5, 2.6, 2.8, 2.9, 10.0], [0, 0, 0.05, 0.05, 0, 0]), QUIET)
    assert front.true_ground_m(0.0) == pytest.approx(-0.05 * 3.7 / 2.7, abs=1e-12)
    assert front.read(0.0) == pytest.approx(0.8 + 0.05 * 3.7 / 2.7, abs=1e-12)


def test_noise_and_resolution():
    s = PreviewSensor(twin([0.0, 10.0], [0.0, 0.0]), PreviewSensorConfig(noise_rms_m=0.003, resolution_m=0.001))
    r = np.array([s.read(0.0) for _ in range(4000)])
    assert np.std(r) == pytest.approx(0.003, rel=0.06)
    assert np.mean(r) == pytest.approx(0.8, abs=3 * 0.003 / np.sqrt(4000) + 5e-4)
    assert np.allclose(np.round(r / 0.001) * 0.001, r)
    with pytest.raises(PreviewSensorError, match="ahead_of_front_axle_m"):
        PreviewSensorConfig(ahead_of_front_axle_m=0.0)
    with pytest.raises(PreviewSensorError, match="seed"):
        PreviewSensorConfig(seed=-1)
