"""The look-ahead ground sensor of the twin: its reading against independent geometry (a least-squares plane
through the four wheel contacts and the world height field), its noise, its configuration and its CAN path
(0xFF26 from its own sender, decoded apart from the implement's ground sensor)."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest

from bridge.isobus.codec import decode
from bridge.isobus.messages import GROUND_AHEAD_SENSOR_ADDRESS, GROUND_SENSOR_ADDRESS, GroundDistance
from bridge.link.tractor_sensors import TractorSensors
from bridge.sim.scenario import ScenarioError, scenario_from_dict
from bridge.sim.sensors import TwinSensors
from bridge.sim.terrain import (
    LookAheadGroundSensor,
    SineGround,
    SpeedProfile,
    TerrainError,
    TerrainTwin,
    TractorGeometry,
    Undulation,
)
from bridge.sim.tractor_node import TractorTwinNode

V = 8 / 3.6
L, T, BEHIND = 2.7, 1.8, 1.2
GROUND = SineGround(undulations=(Undulation(0.03, 7.0), Undulation(0.02, 19.0, 0.5)))


def world(s: float) -> float:
    """The world profile, written out independently of the twin (no cross slope)."""
    return 0.03 * math.sin(2 * math.pi * s / 7.0) + 0.02 * math.sin(2 * math.pi * s / 19.0 + 0.5)


def twin(ahead=4.9, noise=0.0, mount=0.8, seed=0):
    return TerrainTwin(
        ground=GROUND,
        speed=SpeedProfile.constant(V),
        tractor=TractorGeometry(L, T, "rigid"),
        implement_behind_m=BEHIND,
        ground_sensor=LookAheadGroundSensor(ahead_m=ahead, mount_height_m=mount, noise_rms_m=noise, seed=seed),
    )


def true_reading(t: float, ahead: float, mount: float) -> float:
    """Independent: the body's plane is the least-squares plane through the four wheel contacts (rigid
    suspension); the sensor, fixed to the body ``ahead`` ahead of the implement, reads its mount height above
    that plane minus the world ground's height above the plane, at its point."""
    s_r = V * t
    pts = [(s_r, T / 2), (s_r, -T / 2), (s_r + L, T / 2), (s_r + L, -T / 2)]
    A = np.array([[1.0, s - s_r, u] for s, u in pts])
    z = np.array([world(s) for s, _ in pts])
    z0, b, c = np.linalg.lstsq(A, z, rcond=None)[0]
    x = ahead - BEHIND  # ahead of the rear axle
    return mount - (world(s_r + x) - (z0 + b * x))


def test_the_reading_is_the_ground_ahead_relative_to_the_body_plane():
    tw = twin(noise=0.0)
    for t in np.linspace(0.0, 20.0, 41):
        assert tw.ground_ahead_distance_m(float(t)) == pytest.approx(true_reading(float(t), 4.9, 0.8), abs=1e-9)
    # it moves with the body: the reading is not the world ground's height (the tractor pitches and heaves)
    worst = max(abs((0.8 - tw.ground_ahead_distance_m(t)) - world(V * t + 3.7)) for t in np.linspace(0, 20, 41))
    assert worst > 0.02


def test_the_noise_has_the_stated_rms_is_white_and_deterministic():
    tw, clean = twin(noise=0.003, seed=7), twin(noise=0.0)
    ts = np.arange(0.0, 40.0, 0.02)
    e = np.array([tw.ground_ahead_distance_m(float(t)) - clean.ground_ahead_distance_m(float(t)) for t in ts])
    assert np.std(e) == pytest.approx(0.003, rel=0.06)  # 2000 samples: the RMS within ~3 sigma
    assert abs(np.mean(e)) < 4 * 0.003 / math.sqrt(e.size)
    assert abs(np.corrcoef(e[:-1], e[1:])[0, 1]) < 0.1  # white
    assert tw.ground_ahead_distance_m(3.14) == twin(noise=0.003, seed=7).ground_ahead_distance_m(3.14)
    assert tw.ground_ahead_distance_m(3.14) != twin(noise=0.003, seed=8).ground_ahead_distance_m(3.14)


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"ahead_m": 25.0}, "ground_sensor_ahead_m"),
        ({"ahead_m": -1.0}, "ground_sensor_ahead_m"),
        ({"ahead_m": math.nan}, "ground_sensor_ahead_m"),
        ({"mount_height_m": 0.0}, "ground_sensor_mount_height_m"),
        ({"noise_rms_m": 0.2}, "ground_sensor_noise_rms_m"),
        ({"noise_rms_m": -0.001}, "ground_sensor_noise_rms_m"),
        ({"seed": -1}, "seed"),
    ],
)
def test_bad_sensor_values_are_refused_with_the_field_and_range(kw, field):
    with pytest.raises(TerrainError, match=field) as exc:
        LookAheadGroundSensor(**kw)
    assert field == "seed" or "allowed range" in str(exc.value)


def test_scenario_fields_reach_the_twin_and_are_range_checked():
    base = {"schema_version": 1, "name": "t", "duration_s": 10.0, "speed": {"constant_m_s": 1.0}}
    sc = scenario_from_dict({**base, "signals": {"ground_sensor_ahead_m": 4.9, "ground_sensor_noise_rms_m": 0.002}})
    g = sc.twin.ground_sensor
    assert (g.ahead_m, g.noise_rms_m, g.mount_height_m, g.fitted) == (4.9, 0.002, 0.8, True)
    assert not scenario_from_dict(base).twin.ground_sensor.fitted  # default: none fitted
    for bad in ({"ground_sensor_ahead_m": 25.0}, {"ground_sensor_mount_height_m": 5.0}):
        name = next(iter(bad))
        with pytest.raises(ScenarioError, match=name):
            scenario_from_dict({**base, "signals": bad})


def _run_node(tw: TerrainTwin, seconds: float):
    """The twin's node and the planner-side decoder on one virtual bus, polled every 10 ms; the frames seen."""
    ch = f"gsa-{id(tw)}"
    tx, rx, spy = (can.Bus(interface="virtual", channel=ch) for _ in range(3))
    try:
        node = TractorTwinNode(tx, TwinSensors(tw), hitch_height_m=lambda t: 0.6)
        dec = TractorSensors(rx)
        node.start(0.0)
        dec.start(0.0)
        frames = []
        for k in range(round(seconds / 0.01) + 1):
            t = k * 0.01
            node.poll(t)
            dec.poll(t)
            while (m := spy.recv(timeout=0.0)) is not None:
                frames.append((t, m))
        return node, dec, frames
    finally:
        for b in (tx, rx, spy):
            b.shutdown()


def test_the_sensor_travels_the_bus_as_0xff26_from_its_own_sender_and_is_decoded_apart():
    tw = twin(noise=0.0)
    node, dec, frames = _run_node(tw, 1.0)
    assert node.sent("ground_ahead") == 51  # every 20 ms from t = 0
    ahead = [(t, decode(m)) for t, m in frames if m.arbitration_id & 0xFF == GROUND_AHEAD_SENSOR_ADDRESS]
    under = [(t, decode(m)) for t, m in frames if m.arbitration_id & 0xFF == GROUND_SENSOR_ADDRESS]
    assert len(ahead) == 51 and len(under) == 51
    for t, p in ahead:
        assert isinstance(p, GroundDistance)
        assert p.distance_m == pytest.approx(true_reading(t, 4.9, 0.8), abs=1e-4)  # 0.1 mm steps
    r = dec.readings(1.0)
    assert r.ground_distance_ahead.value == pytest.approx(true_reading(1.0, 4.9, 0.8), abs=1e-4)
    assert r.ground_distance_ahead.received_s == pytest.approx(1.0)
    # the implement's sensor keeps its own reading (0.6 m high over the ground under the implement)
    assert r.ground_distance.value == pytest.approx(tw.ground_distance_m(1.0, 0.6), abs=1e-4)
    assert r.signal("ground_distance_ahead") is r.ground_distance_ahead


def test_without_a_look_ahead_sensor_nothing_is_sent_and_nothing_is_missed():
    tw = twin(ahead=0.0)
    node, dec, frames = _run_node(tw, 0.5)
    assert node.sent("ground_ahead") == 0
    assert not any(m.arbitration_id & 0xFF == GROUND_AHEAD_SENSOR_ADDRESS for _, m in frames)
    r = dec.readings(0.5)
    assert r.ground_distance_ahead.value is None and r.ground_distance_ahead.stale
    assert "ground_distance_ahead" not in r.unusable()  # an optional sensor is not reported missing
    assert TwinSensors(tw).ground_ahead(0.1).distance_m is None
