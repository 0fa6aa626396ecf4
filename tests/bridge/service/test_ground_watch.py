"""The stuck ground-distance check of frame ``ground`` (bridge.service.motion.ground_watch), on hand-made histories.

Truth: the rule itself (readings within a 3 mm band for 1 s while the setpoints ask for more than 10 mm and the
hitch moved more than 40 mm), and a real sensor over a hitch following the ground never looking stuck.
"""

from __future__ import annotations

import numpy as np
import pytest

from bridge.service.motion.ground_watch import GroundWatch


def _run(watch: GroundWatch, d, z, dt: float = 0.02) -> list[tuple[float, str | None]]:
    return [(k * dt, watch.check(float(dk), float(zk), k * dt)) for k, (dk, zk) in enumerate(zip(d, z, strict=True))]


def test_a_reading_held_while_the_hitch_moves_is_stuck_after_frozen_s_and_not_before():
    n = 100  # 2 s at 50 Hz
    z = np.linspace(0.30, 0.20, n)  # the hitch lowered 100 mm over 2 s: 50 mm per second
    got = _run(GroundWatch(), np.full(n, 0.30), z)
    first = next(t for t, why in got if why is not None)
    assert abs(first - 1.0) < 1e-9
    why = dict(got)[first]
    assert why is not None and why.startswith(
        "the ground distance stayed at 0.300 m for 1.0 s while the hitch moved 51 mm"
    )


def test_a_held_reading_at_rest_or_a_small_move_is_not_stuck():
    n = 250
    assert all(w is None for _, w in _run(GroundWatch(), np.full(n, 0.30), np.full(n, 0.25)))
    z = 0.25 + 0.019 * np.sin(np.linspace(0, 6, n))  # ±19 mm: 38 mm range, under 40
    assert all(w is None for _, w in _run(GroundWatch(), np.full(n, 0.30), z))


def test_a_real_sensors_noise_while_the_hitch_follows_the_ground_is_never_stuck():
    rng = np.random.default_rng(3)
    n = 1500  # 30 s of terrain following: the hitch moves ±50 mm, the reading keeps near its setpoint
    z = 0.25 + 0.05 * np.sin(np.linspace(0, 20, n))
    d = np.round((0.30 + rng.normal(0.0, 0.001, n)) * 1000) / 1000  # 1 mm resolution, 1 mm RMS
    assert all(w is None for _, w in _run(GroundWatch(), d, z))


@pytest.mark.parametrize("seconds, speed_m_s", [(3.0, 0.05), (6.0, 0.025), (30.0, 0.005)])
def test_a_reading_at_its_setpoint_while_the_hitch_follows_a_steady_grade_is_not_stuck(seconds, speed_m_s):
    """Two reviews: a 1 mm sensor tracked to within 0.2 mm reads one value while the hitch ramps on a steady
    grade — the setpoint asks for nothing (the reading is at it), so nothing runs away, however far (the 120 mm
    rule counting whatever was asked stopped these at 2.4, 4.8 and 24 s)."""
    n = int(round(seconds / 0.02))
    z = 0.25 - speed_m_s * 0.02 * np.arange(n)
    watch = GroundWatch()
    assert all(watch.check(0.30, float(zk), k * 0.02, asked_m=0.0004) is None for k, zk in enumerate(z))
    watch = GroundWatch()  # the same reading under a setpoint 50 mm lower: stuck once held 1 s and moved 40 mm
    got = [watch.check(0.30, float(zk), k * 0.02, asked_m=-0.05) for k, zk in enumerate(z)]
    first = next(k for k, w in enumerate(got) if w is not None)
    assert first == next(k for k in range(n) if k * 0.02 >= 1.0 - 1e-9 and z[0] - z[k] > 0.04), first


def test_a_sensor_dithering_by_its_resolution_step_is_stuck_too():
    """A recheck of the fix: a sensor alternating 0.300 / 0.301 m (pointed at a part of the tractor) reset a 1 µm
    band every reading and the hitch ran to its bottom limit."""
    n = 100
    z = np.linspace(0.30, 0.20, n)
    d = np.where(np.arange(n) % 2 == 0, 0.300, 0.301)
    watch = GroundWatch()
    got = [
        watch.check(float(dk), float(zk), k * 0.02, asked_m=-0.05) for k, (dk, zk) in enumerate(zip(d, z, strict=True))
    ]
    first = next(k for k, w in enumerate(got) if w is not None)
    assert first * 0.02 == 1.0
    assert "stayed within 0.300 … 0.301 m for 1.0 s" in str(got[first])


def test_a_reading_held_under_a_setpoint_a_few_millimetres_away_is_stuck_once_the_hitch_ran_beyond_the_ground():
    """A review: a sensor stuck at 0.300 m under a setpoint of 0.291 m asks for 9 mm (under ``asked_min_m``) again
    every cycle; the hitch crept 17 mm/s to its bottom limit, 333 mm, never noticed. Stuck once the hitch moved
    more than ``moved_far_m`` (120 mm) with that one reading, whatever is asked, and not before."""
    dt, n = 0.02, 1000  # 20 s
    z = 0.1156 - 0.017 * dt * np.arange(n)  # the run the review measured
    watch = GroundWatch()
    got = [watch.check(0.300, float(zk), k * dt, asked_m=-0.009) for k, zk in enumerate(z)]
    first = next(k for k, w in enumerate(got) if w is not None)
    assert 0.120 < z[0] - z[first] <= 0.120 + 0.017 * dt + 1e-12, z[0] - z[first]
    assert "stayed at 0.300 m for 7.1 s while the hitch moved 120 mm: a stuck ground-distance sensor" in str(got[first])
    # the same reading with real noise (3 mm RMS, the twin's sensor) while the hitch follows the ground: never
    rng = np.random.default_rng(7)
    noisy = GroundWatch()
    zz = 0.25 + 0.05 * np.sin(np.linspace(0.0, 20.0, n))
    d = 0.30 + rng.normal(0.0, 0.003, n)
    assert all(
        noisy.check(float(dk), float(zk), k * dt, asked_m=0.0) is None
        for k, (dk, zk) in enumerate(zip(d, zz, strict=True))
    )
