"""AD scaling (thesis tables 3-1, 3-2)."""

import numpy as np
import pytest

from planner.model.sensors import SensorRangeError, SensorScaling
from planner.profiles.hitch import load_profile


def test_calibration_end_points_and_round_trip():
    s = SensorScaling(load_profile())
    np.testing.assert_array_equal(s.to_counts(s.si_min), [26, 26, 26, 30, 26])
    np.testing.assert_array_equal(s.to_counts(s.si_max), [255, 917, 255, 510, 503])
    assert s.to_si([26, 917, 255, 30, 503]) == pytest.approx([-0.223, 0.730, 0.905, 0.500, 0.575])
    rng = np.random.default_rng(3)
    for _ in range(100):
        c = np.rint(s.counts_min + (s.counts_max - s.counts_min) * rng.random(5)).astype(int)
        np.testing.assert_array_equal(s.to_counts(s.to_si(c)), c)
    # tilt resolution: 150 mm over 891 counts
    assert s.resolution[1] == pytest.approx(0.150 / 891)


def test_out_of_range_readings_are_reported_not_clamped():
    s = SensorScaling(load_profile())
    with pytest.raises(SensorRangeError, match=r"tilt reading 1000\.0 counts outside the calibrated span \[26, 917\]"):
        s.to_si([100, 1000, 100, 100, 100])
    with pytest.raises(SensorRangeError, match=r"left command .* outside"):
        s.to_counts([0.2, 0.6, 0.7, 0.7, 0.55])
