"""Wheel-based distance over CAN (PGN 65096): the simulated tractor and the odometer on a private
virtual bus, in simulated time. Truth: distance = speed × time (to one send period), the field's
wrap-around, and the codec's frames for hand-made cases."""

from __future__ import annotations

import uuid

import can
import pytest

from bridge.isobus.codec import WheelBasedSpeed, encode
from bridge.isobus.j1939 import MachineDirection
from bridge.service.odometer import DISTANCE_WRAP_M, SimulatedTractor, WheelOdometer


@pytest.fixture
def buses():
    ch = f"odo-{uuid.uuid4().hex}"
    bs = [can.Bus(interface="virtual", channel=ch) for _ in range(2)]
    yield bs
    for b in bs:
        b.shutdown()


def test_distance_is_speed_times_time(buses):
    tractor, odo = SimulatedTractor(buses[0], 2.5), WheelOdometer(buses[1])
    tractor.start(0.0)
    odo.start(0.0)
    assert odo.distance_m() is None  # nothing heard yet
    t = 0.0
    while t < 10.0 - 1e-9:
        t = round(t + 0.01, 6)
        tractor.poll(t)
        odo.poll(t)
    assert odo.frames == pytest.approx(100, abs=1)
    assert odo.distance_m() == pytest.approx(2.5 * 10.0, abs=2.5 * 0.1 + 1e-3)  # the last frame is ≤ 0.1 s old
    for k in range(1, 200):  # the tractor stops talking: stale after 1 s
        odo.poll(t + 0.01 * k)
    assert odo.distance_m() is None


def send(bus, distance, speed=1.0, source=240):
    bus.send(
        encode(WheelBasedSpeed(speed_m_s=speed, distance_m=distance, direction=MachineDirection.FORWARD), source=source)
    )


def test_wrap_reset_and_foreign_sources(buses):
    tx, odo = buses[0], WheelOdometer(buses[1])
    odo.start(0.0)
    send(tx, DISTANCE_WRAP_M - 1.0)
    odo.poll(0.1)
    send(tx, 2.0)  # wrapped: 3 m travelled
    odo.poll(0.2)
    assert odo.distance_m() == pytest.approx(3.0, abs=1e-3)
    send(tx, 7.0, source=17)  # another node's frame is not our tractor
    odo.poll(0.3)
    assert odo.distance_m() == pytest.approx(3.0, abs=1e-3)
    send(tx, 100_000.0)  # the sender's odometer was reset: not travel
    odo.poll(0.4)
    send(tx, 100_004.5)
    odo.poll(0.5)
    assert odo.distance_m() == pytest.approx(7.5, abs=1e-3)
    tx.send(can.Message(arbitration_id=0x0CFE48F0, data=b"\x01\x02", is_extended_id=True))  # wrong DLC
    odo.poll(0.6)
    assert odo.malformed == 1 and odo.distance_m() == pytest.approx(7.5, abs=1e-3)


def test_speed_is_integrated_when_the_distance_field_is_missing(buses):
    tx, odo = buses[0], WheelOdometer(buses[1])
    odo.start(0.0)
    for k in range(11):
        tx.send(encode(WheelBasedSpeed(speed_m_s=2.0), source=240))
        odo.poll(0.1 * k)
    assert odo.distance_m() == pytest.approx(2.0, abs=1e-9)  # 10 intervals of 0.1 s at 2 m/s


def test_bad_settings_are_refused(buses):
    with pytest.raises(ValueError, match="speed_m_s"):
        SimulatedTractor(buses[0], float("nan"))
    with pytest.raises(ValueError, match="stale_after_s"):
        WheelOdometer(buses[1], stale_after_s=0.0)
