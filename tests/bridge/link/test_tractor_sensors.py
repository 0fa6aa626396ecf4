"""The planner-side tractor sensors from hand-made frames (no simulator): decoding, "not available"
and error values, figures of merit, the rate bounds, senders, malformed frames, thread safety and the
odometer contract. Truth: the values encoded by the codec, the documented bounds, and
:class:`bridge.service.odometer.WheelOdometer` fed the same frames."""

from __future__ import annotations

import math
import threading
import uuid

import can
import pytest

from bridge.isobus.codec import encode
from bridge.isobus.j1939 import CYLINDER_ECU_ADDRESS, MachineDirection, Switch
from bridge.isobus.messages import (
    FigureOfMerit,
    GroundDistance,
    RearHitchStatus,
    RowGuidance,
    SlopeSensorInformation,
    SlopeSensorInformation2,
    WheelBasedSpeed,
)
from bridge.link.state import LinkError
from bridge.link.tractor_sensors import (
    SIGNALS,
    Plausibility,
    TractorSensors,
    TractorSensorsConfig,
)
from bridge.service.odometer import DISTANCE_WRAP_M, WheelOdometer

OK = FigureOfMerit.FULLY_FUNCTIONAL
ECU = CYLINDER_ECU_ADDRESS
RES = math.radians(0.002)


@pytest.fixture
def channel():
    return f"tsens-{uuid.uuid4().hex}"


@pytest.fixture
def bench(channel):
    tx, rx = can.Bus(interface="virtual", channel=channel), can.Bus(interface="virtual", channel=channel)
    yield tx, TractorSensors(rx)
    tx.shutdown()
    rx.shutdown()


def ssi(roll=0.0, pitch=0.0, rate=0.0, *, roll_merit=OK, latency=0.01):
    return SlopeSensorInformation(
        pitch_rad=pitch,
        roll_rad=roll,
        pitch_rate_rad_s=rate,
        pitch_merit=OK,
        roll_merit=roll_merit,
        pitch_rate_merit=OK,
        compensated=Switch.ON,
        latency_s=latency,
    )


def feed(tx, sensors, payload, t, **kw):
    tx.send(encode(payload, **kw))
    sensors.poll(t)


def test_values_decode_within_resolution(bench):
    tx, s = bench
    s.start(0.0)
    before = s.readings()
    assert all(before.signal(n).value is None and before.signal(n).stale for n in SIGNALS)
    assert before.roll.reason == "no frame received yet"
    feed(tx, s, ssi(roll=0.0523, pitch=-0.031, rate=0.2), 0.01)
    feed(tx, s, GroundDistance(0.43217, OK), 0.02)
    feed(tx, s, RowGuidance(-0.01234, OK), 0.03)
    feed(tx, s, WheelBasedSpeed(speed_m_s=2.222, distance_m=10.0, direction=MachineDirection.FORWARD), 0.04)
    r = s.readings()
    assert r.roll.value == pytest.approx(0.0523, abs=RES) and r.roll.received_s == 0.01
    assert r.pitch.value == pytest.approx(-0.031, abs=RES)
    assert r.pitch_rate.value == pytest.approx(0.2, abs=RES)
    assert r.ground_distance.value == pytest.approx(0.43217, abs=1e-4)
    assert r.row_offset.value == pytest.approx(-0.01234, abs=1e-4)
    assert r.speed.value == pytest.approx(2.222, abs=1e-3) and r.distance.value == 0.0
    assert r.slope_latency_s == pytest.approx(0.01)
    assert r.unusable() == {} and r.fresh(0.04, 0.05)
    assert not r.fresh(0.04, 0.025)  # the slope frame is 30 ms old
    assert r.roll.age_s(0.04) == pytest.approx(0.03)
    feed(tx, s, SlopeSensorInformation2(pitch_rad=0.01, roll_rad=0.06, roll_merit=OK, pitch_merit=OK), 0.05)
    r = s.readings()
    assert r.roll.value == pytest.approx(0.06, abs=1e-6) and r.pitch.value == pytest.approx(0.01, abs=1e-6)
    assert r.pitch_rate.received_s == 0.01  # SSI2 carries no pitch rate
    assert s.counters().frames == 5 and s.counters().errors == 0


def test_not_available_error_and_figures_of_merit_are_reasons_never_nan(bench):
    tx, s = bench
    feed(tx, s, ssi(roll=0.01), 0.0)
    feed(tx, s, ssi(roll=0.01, roll_merit=FigureOfMerit.ERROR), 0.01)
    assert s.readings().roll.value is None and s.readings().roll.reason == "figure of merit: error"
    feed(tx, s, ssi(roll=0.01, roll_merit=FigureOfMerit.NOT_AVAILABLE), 0.02)
    assert s.readings().roll.reason == "figure of merit: not available"
    feed(tx, s, ssi(roll=0.01, roll_merit=FigureOfMerit.DEGRADED), 0.03)
    assert s.readings().roll.value == pytest.approx(0.01, abs=RES)  # degraded: used, counted
    assert s.counters().degraded == 1
    # raw 0xFFFF (not available) and 0xFExx (error indicator) in the roll field
    for raw, reason in ((b"\xff\xff", "not available"), (b"\x00\xfe", "error indicator")):
        good = bytearray(encode(ssi(roll=0.01)).data)
        good[2:4] = raw
        tx.send(can.Message(arbitration_id=encode(ssi()).arbitration_id, data=bytes(good), is_extended_id=True))
        s.poll(0.04)
        r = s.readings()
        assert r.roll.value is None and r.roll.reason == reason and not r.roll.stale
        assert r.pitch.value is not None  # the other fields of the frame stay usable
    feed(tx, s, GroundDistance(None, FigureOfMerit.NOT_AVAILABLE), 0.05)
    assert s.readings().ground_distance.reason == "not available"
    feed(tx, s, RowGuidance(None, FigureOfMerit.ERROR), 0.05)
    assert s.readings().row_offset.reason == "figure of merit: error"
    assert s.readings().unusable()["roll"] == "error indicator"
    for n in SIGNALS:
        v = s.readings().signal(n).value
        assert v is None or math.isfinite(v)


def _stamped(payload, stamp_s, **kw):
    msg = encode(payload, **kw)
    msg.timestamp = stamp_s
    return msg


def test_frames_that_waited_out_a_stall_are_judged_by_their_own_spacing():
    """A host stall: frames queue in the bus and the runner takes them all at one node time.
    Before, the rate bound then shrank to the slack alone: two draft readings 10 ms apart were an
    "implausible jump" (the draft's slack is 0), the draft went None and work control fell back to
    position for good (CI, under load); a ground distance moving 30 mm in 10 ms (3 m/s, within
    5 m/s) was dropped too. Their bus timestamps keep the real spacing; a spike is still dropped."""
    s = TractorSensors(_Port(), TractorSensorsConfig(read_draft=True))
    t0 = 1000.0  # the bus's clock (any: only differences count)
    s.take(_stamped(RearHitchStatus(draft_n=8_000.0), t0, source=ECU), 5.0)
    s.take(_stamped(RearHitchStatus(draft_n=8_230.0), t0 + 0.01, source=ECU), 5.0)  # the same node time: one burst
    assert s.draft(5.0).value == pytest.approx(8_230.0, abs=10.0)
    s.take(_stamped(RearHitchStatus(draft_n=9_000.0), 0.0, source=ECU), 5.0)  # the draft has no rate bound
    assert s.draft(5.0).value == pytest.approx(9_000.0, abs=10.0) and s.counters().implausible == 0
    s.take(_stamped(GroundDistance(0.40, OK), t0), 5.0)
    s.take(_stamped(GroundDistance(0.43, OK), t0 + 0.01), 5.0)  # 3 m/s: real
    assert s.readings(5.0).ground_distance.value == pytest.approx(0.43, abs=RES)
    s.take(_stamped(GroundDistance(0.60, OK), t0 + 0.02), 5.0)  # 17 m/s: a spike, dropped
    assert s.readings(5.0).ground_distance.value is None and s.counters().implausible == 1
    s.take(_stamped(GroundDistance(0.44, OK), t0 + 0.03), 5.0)
    assert s.readings(5.0).ground_distance.value == pytest.approx(0.44, abs=RES)
    # a foreign clock cannot open the bound beyond the signal's stale time (0.2 s: 1 m + 0.01 m at 5 m/s)
    s.take(_stamped(GroundDistance(2.0, OK), t0 + 1_000.0), 5.0)
    assert s.readings(5.0).ground_distance.value is None and s.counters().implausible == 2
    s.take(_stamped(GroundDistance(1.2, OK), t0 + 2_000.0), 5.0)  # 0.76 m: within 5 m/s · 0.2 s + 0.01 m
    assert s.readings(5.0).ground_distance.value == pytest.approx(1.2, abs=RES)
    # the node times' difference still counts when the timestamps say less
    s.take(_stamped(GroundDistance(1.6, OK), t0 + 2_000.0), 5.1)
    assert s.readings(5.1).ground_distance.value == pytest.approx(1.6, abs=RES)


class _Port:
    """A bus for :meth:`TractorSensors.take` alone (nothing is read from it)."""

    def recv(self, timeout=None):
        return None


def test_jumps_beyond_the_rate_bound_are_refused_then_recover(bench):
    tx, s = bench
    feed(tx, s, ssi(roll=0.0), 0.0)
    feed(tx, s, ssi(roll=0.0095), 0.01)  # 0.95 rad/s: within 1 rad/s · 10 ms + 2 mrad
    assert s.readings().roll.value == pytest.approx(0.0095, abs=RES)
    feed(tx, s, ssi(roll=0.5), 0.02)  # a spike
    r = s.readings()
    assert r.roll.value is None and r.roll.reason.startswith("implausible jump")
    assert r.pitch.value is not None and s.counters().implausible == 1
    feed(tx, s, ssi(roll=0.01), 0.03)  # back near the last good value: accepted
    assert s.readings().roll.value == pytest.approx(0.01, abs=RES)
    # a lasting step of 0.3 rad is accepted once 0.3 rad / 1 rad/s have passed since the last good value
    t, first_ok = 0.03, None
    while t < 1.0:
        t = round(t + 0.01, 6)
        feed(tx, s, ssi(roll=0.31), t)
        if first_ok is None and s.readings().roll.value is not None:
            first_ok = t
    assert first_ok is not None and 0.03 + 0.298 - 0.011 <= first_ok <= 0.03 + 0.30 + 0.011
    # the ground distance: 5 m/s bound
    feed(tx, s, GroundDistance(0.5, OK), 1.0)
    feed(tx, s, GroundDistance(0.55, OK), 1.02)  # 2.5 m/s: accepted
    feed(tx, s, GroundDistance(3.0, OK), 1.04)  # an echo lost: refused
    assert s.readings().ground_distance.value is None
    assert "implausible" in s.readings().ground_distance.reason


def test_senders_pgns_and_malformed_frames(bench):
    tx, s = bench
    feed(tx, s, ssi(roll=0.1), 0.0, source=17)  # not our slope sensor
    feed(tx, s, GroundDistance(0.3, OK), 0.0, source=228)
    assert s.readings().roll.value is None and s.readings().ground_distance.value is None
    assert s.counters().ignored == 2 and s.counters().frames == 0
    tx.send(can.Message(arbitration_id=0x0CF013E2, data=b"\x01\x02", is_extended_id=True))  # SSI with DLC 2
    tx.send(can.Message(arbitration_id=0x123, data=b"\x00" * 8, is_extended_id=False))
    tx.send(can.Message(arbitration_id=0x18FF24E2, data=b"\x00" * 8, is_extended_id=True))  # unknown PGN
    s.poll(0.1)
    c = s.counters()
    assert (c.frames, c.errors, c.ignored) == (1, 1, 4)
    anyone = TractorSensors(s.bus, TractorSensorsConfig(slope_source=None))
    feed(tx, anyone, ssi(roll=0.1), 0.2, source=17)
    assert anyone.readings().roll.value == pytest.approx(0.1, abs=RES)


def test_bad_settings_are_refused(bench):
    _, s = bench
    with pytest.raises(LinkError, match="slope_stale_after_s"):
        TractorSensorsConfig(slope_stale_after_s=0.0)
    with pytest.raises(LinkError, match="wheel_source"):
        TractorSensorsConfig(wheel_source=300)
    with pytest.raises(LinkError, match="attitude_rate_rad_s"):
        Plausibility(attitude_rate_rad_s=float("nan"))
    with pytest.raises(LinkError, match="signal"):
        s.readings().signal("yaw")
    assert issubclass(LinkError, ValueError)


def test_distance_is_the_odometers(bench, channel):
    tx, s = bench
    other = can.Bus(interface="virtual", channel=channel)  # the odometer hears the same frames
    try:
        odo = WheelOdometer(other)
        seq = [DISTANCE_WRAP_M - 1.0, 2.0, 100_000.0, 100_004.5, None, None]
        for k, d in enumerate(seq):
            tx.send(encode(WheelBasedSpeed(speed_m_s=2.0, distance_m=d), source=240))
            s.poll(0.1 * k)
            odo.poll(0.1 * k)
            assert s.distance_m() == odo.distance_m()
        assert s.distance_m() == pytest.approx(3.0 + 4.5 + 0.4, abs=1e-6)  # the wrap, a reset, then 2 × 0.1 s at 2 m/s
        s.poll(1.7)
        odo.poll(1.7)
        assert s.distance_m() is None and odo.distance_m() is None  # stale after 1 s
        assert s.readings().distance.stale and s.readings().distance.value == pytest.approx(7.9, abs=1e-6)
    finally:
        other.shutdown()


def test_snapshots_are_consistent_across_threads(bench):
    tx, s = bench
    errors: list[str] = []
    done = threading.Event()

    def reader():
        while not done.is_set():
            r = s.readings()
            if r.roll.value is not None and r.pitch.value is not None and abs(r.roll.value + r.pitch.value) > 1e-3:
                errors.append(f"torn snapshot {r.roll.value} {r.pitch.value}")

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    try:
        for k in range(300):  # roll = -pitch in every frame: a snapshot must never mix two frames
            v = 0.001 * (k % 10)
            tx.send(encode(ssi(roll=v, pitch=-v)))
            s.poll(0.01 * k)
    finally:
        done.set()
        th.join(5.0)
    assert not errors and s.counters().frames == 300
