"""The measured draft over the bus: a draft source in the simulated ECU node → the ISO 11783-7 rear
hitch status (RearDraft, nominal lower-link force) → the planner side's TractorSensors. Checked
against the values the source gave (10 N/bit, 0.8 %/bit quantisation), decoded independently."""

from __future__ import annotations

import uuid

import can
import pytest

from bridge.isobus.codec import decode_frame
from bridge.isobus.j1939 import PGN_REAR_HITCH_STATUS, Switch, decode_id
from bridge.link.tractor_sensors import TractorSensors, TractorSensorsConfig
from bridge.sim import CylinderECU
from bridge.sim.can_node import EcuCanNode
from bridge.sim.draft_sensor import rear_hitch_status
from planner.errors import HitchInputError


@pytest.fixture
def buses():
    channel = f"test-{uuid.uuid4().hex}"
    opened = [can.Bus(interface="virtual", channel=channel) for _ in range(3)]
    yield opened
    for b in opened:
        b.shutdown()


def _run(nodes, t_to, listener, t_from=0.0):
    frames = []
    for k in range(int(round(t_from / 0.001)) + 1, int(round(t_to / 0.001)) + 1):
        t = k * 0.001
        for n in nodes:
            n.poll(t)
        while (f := listener.recv(timeout=0.0)) is not None:
            frames.append((t, f))
    return frames


def test_draft_source_reaches_the_planner_side_through_the_hitch_status(buses):
    node_bus, sensor_bus, listener = buses
    node = EcuCanNode(CylinderECU(), node_bus)
    sensors = TractorSensors(sensor_bus, TractorSensorsConfig(read_draft=True))
    plain = TractorSensors(listener)  # default: the hitch status is not read
    asked: list[float] = []

    def source(now_s: float):
        asked.append(now_s)
        return rear_hitch_status(12_000.0 + 1000.0 * now_s, nominal_force_n=40_000.0, in_work=Switch.ON)

    node.draft_source = source
    node.start(0.0)
    sensors.start(0.0)
    frames = _run([node, sensors], 0.5, listener)
    hitch = [(t, f) for t, f in frames if decode_id(f.arbitration_id).pgn == PGN_REAR_HITCH_STATUS]
    assert hitch and asked  # the node asked its source when each frame was due
    t_last, last = hitch[-1]
    p = decode_frame(last).payload
    want = 12_000.0 + 1000.0 * t_last
    assert p.draft_n == pytest.approx(want, abs=5.0)  # 10 N/bit
    assert p.nominal_lower_link_force == pytest.approx(want / 40_000.0, abs=0.004)  # 0.8 %/bit
    assert p.in_work is Switch.ON and p.position is not None  # the lift is still the node's own
    r = sensors.draft(t_last)
    assert r.usable and r.received_s == pytest.approx(t_last) and r.value == pytest.approx(want, abs=5.0)
    assert r.value == p.draft_n
    assert not sensors.draft(t_last + 0.31).usable  # stale after 0.3 s without a frame
    for t, f in hitch:
        plain.take(f, t)
    assert plain.draft().value is None and plain.draft().reason == "no frame received yet"


def test_a_missing_draft_is_sent_and_read_as_not_available(buses):
    node_bus, sensor_bus, listener = buses
    node = EcuCanNode(CylinderECU(), node_bus)  # no draft source: the draft fields are not available
    sensors = TractorSensors(sensor_bus, TractorSensorsConfig(read_draft=True))
    node.start(0.0)
    _run([node, sensors], 0.3, listener)
    r = sensors.draft()
    assert r.value is None and r.reason == "not available" and r.received_s is not None
    node.draft_source = lambda now_s: rear_hitch_status(5000.0, nominal_force_n=40_000.0)
    _run([node, sensors], 0.35, listener, t_from=0.3)
    assert sensors.draft().value == pytest.approx(5000.0)
    node.draft_source = lambda now_s: None  # the source has nothing: not available again
    _run([node, sensors], 0.4, listener, t_from=0.35)
    assert sensors.draft().value is None


def test_draft_reading_settings_are_validated():
    for kw, name in (({"read_draft": 1}, "read_draft"), ({"hitch_source": 300}, "hitch_source")):
        with pytest.raises(HitchInputError, match=name):
            TractorSensorsConfig(**kw)
    with pytest.raises(HitchInputError, match="draft_stale_after_s"):
        TractorSensorsConfig(draft_stale_after_s=0.0)
