"""The twin's tractor on a private virtual bus, read by the planner-side :class:`TractorSensors`, in
simulated time (integer ticks, as :class:`bridge.sim.rig.SimRig`).

Truth used: the terrain twin's own values (roll/pitch/pitch rate within the SSI resolution 0.002 deg,
ground distance within 0.1 mm, row offset within its 0.1 mm resolution), the levelling scenario's
side slope computed here from the numbers in ``levelling.toml`` (on a pure side slope with the
oscillating front axle roll = the rear axle's cross slope), the DBC cycle times (frame counts over
10 s), and for the default twin the frames of the constant-speed tractor it replaced: a verbatim
copy of that sender below, plus bytes packed by hand from the ISO 11783-7 layout.
"""

from __future__ import annotations

import math
import struct
import uuid

import can
import numpy as np
import pytest

from bridge.isobus.codec import encode
from bridge.isobus.j1939 import PGN_WHEEL_BASED_SPEED, MachineDirection, decode_id
from bridge.isobus.messages import (
    PGN_GROUND_DISTANCE,
    PGN_ROW_GUIDANCE,
    PGN_SLOPE_SENSOR_INFORMATION,
    WheelBasedSpeed,
)
from bridge.link.realtime import RealtimeRunner
from bridge.link.tractor_sensors import TractorSensors
from bridge.service.odometer import SimulatedTractor
from bridge.sim.rig import SimRig
from bridge.sim.scenario import load_scenario
from bridge.sim.sensors import DISTANCE_WRAP_M, TwinSensors
from bridge.sim.tractor_node import TractorNodeConfig, TractorNodeError, TractorTwinNode, hitch_height_from_ecu
from planner.errors import HitchInputError

SSI_RES_RAD = math.radians(0.002)
MM_01 = 1e-4


@pytest.fixture
def channel():
    buses: list[can.BusABC] = []
    ch = f"tractor-{uuid.uuid4().hex}"

    def open_() -> can.BusABC:
        b = can.Bus(interface="virtual", channel=ch)
        buses.append(b)
        return b

    yield open_
    for b in buses:
        b.shutdown()


def drain(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (m := bus.recv(timeout=0.0)) is not None:
        out.append(m)
    return out


def pgn_of(m: can.Message) -> int:
    return decode_id(m.arbitration_id).pgn


class HeadSimulatedTractor:
    """The constant-speed sender the twin replaced, copied verbatim (its ``poll``) as the reference."""

    def __init__(self, bus, speed_m_s, *, period_s=0.1, source=240):
        self._bus = bus
        self.speed_m_s, self.period_s, self.source = float(speed_m_s), float(period_s), source
        self._distance = 0.0
        self._t_last = None
        self._due = 0.0

    def start(self, now_s):
        self._t_last, self._due = now_s, now_s

    def poll(self, now_s):
        while self._bus.recv(timeout=0.0) is not None:
            pass
        if self._t_last is None:
            self.start(now_s)
            elapsed = 0.0
        else:
            elapsed = now_s - self._t_last
        self._distance = (self._distance + self.speed_m_s * elapsed) % DISTANCE_WRAP_M
        self._t_last = now_s
        if now_s + 1e-9 >= self._due:
            self._due = max(self._due + self.period_s, now_s)
            msg = WheelBasedSpeed(
                speed_m_s=self.speed_m_s, distance_m=round(self._distance, 3), direction=MachineDirection.FORWARD
            )
            self._bus.send(encode(msg, source=self.source))


# -- the default twin is the former SimulatedTractor ------------------------------------------


@pytest.mark.parametrize("speed", [0.0, 2.0, 2.2222, 2.5, 13.9, 20.0, 64.0])
@pytest.mark.parametrize("timing", ["ticks", "jitter"])
def test_default_twin_sends_the_former_frames_byte_for_byte(channel, speed, timing):
    ref_tx, ref_rx = channel(), channel()
    ch2 = f"tractor-{uuid.uuid4().hex}"
    twin_tx, alias_tx = can.Bus(interface="virtual", channel=ch2), can.Bus(interface="virtual", channel=ch2)
    twin_rx = can.Bus(interface="virtual", channel=ch2)
    try:
        ref = HeadSimulatedTractor(ref_tx, speed)
        twin = TractorTwinNode(twin_tx, ground_speed_m_s=speed)  # every stream: 65096 filtered below
        alias = SimulatedTractor(alias_tx, speed)
        if timing == "ticks":
            times = [k / 1000.0 for k in range(0, 10_001, 10)]
        else:  # a loaded real-time thread: irregular polls from 0.1 to 30 ms
            rng = np.random.default_rng(7)
            times = list(np.cumsum(rng.uniform(1e-4, 0.03, 600)).astype(float))
        for n in (ref, twin, alias):
            n.start(times[0])
        for t in times:
            ref.poll(t)
            twin.poll(t)
            alias.poll(t)
        expected = [(m.arbitration_id, bytes(m.data)) for m in drain(ref_rx)]
        got = drain(twin_rx)
        twin_frames = [(m.arbitration_id, bytes(m.data)) for m in got if m.arbitration_id & 0xFFFF00 == 0xFE4800]
        assert len(expected) >= 90
        # the full twin and the alias each sent exactly the reference's frames (interleaved on the bus)
        assert twin_frames[0::2] == expected and twin_frames[1::2] == expected
        assert alias.sent("wheel_speed") == twin.sent("wheel_speed") == len(expected)
        assert alias.sent("slope") == 0 and twin.sent("slope") > 0  # the alias sends 65096 only
    finally:
        for b in (twin_tx, alias_tx, twin_rx):
            b.shutdown()


def test_default_frames_match_the_iso_layout_packed_by_hand(channel):
    tx, rx = channel(), channel()
    node = TractorTwinNode(tx, ground_speed_m_s=2.5, config=TractorNodeConfig(streams=("wheel_speed",)))
    node.start(0.0)
    for k in range(0, 1001):
        node.poll(k / 100.0)
    frames = drain(rx)
    assert len(frames) == 101  # 0, 0.1, …, 10.0 s
    for i, m in enumerate(frames):
        # priority 3, PGN 0xFE48, source 240; speed 2500 mm/s, distance 250·i mm, max time n/a,
        # direction forward (01) with key switch, start/stop, reversed not available (11)
        assert m.arbitration_id == 0x0CFE48F0 and m.is_extended_id
        assert bytes(m.data) == struct.pack("<HIBB", 2500, 250 * i, 0xFF, 0b11111101)


def test_simulated_tractor_keeps_its_settings_and_errors(channel):
    bus = channel()
    with pytest.raises(HitchInputError, match="speed_m_s"):
        SimulatedTractor(bus, 65.0)
    with pytest.raises(HitchInputError, match="period_s"):
        SimulatedTractor(bus, 1.0, period_s=0.001)
    t = SimulatedTractor(bus, 1.5, period_s=0.2, source=17)
    assert (t.speed_m_s, t.period_s, t.source) == (1.5, 0.2, 17)
    assert isinstance(t, TractorTwinNode)


def test_bad_node_settings_are_refused(channel):
    bus = channel()
    with pytest.raises(TractorNodeError, match="exactly one"):
        TractorTwinNode(bus)
    with pytest.raises(TractorNodeError, match="ground_speed_m_s"):
        TractorTwinNode(bus, ground_speed_m_s=float("nan"))
    with pytest.raises(TractorNodeError, match="slope_period_s"):
        TractorNodeConfig(slope_period_s=0.0)
    with pytest.raises(TractorNodeError, match="streams"):
        TractorNodeConfig(streams=("speed",))
    with pytest.raises(TractorNodeError, match="row_source"):
        TractorNodeConfig(row_source=254)


# -- scenario twin decoded on the planner side ------------------------------------------------


class Bench:
    """Twin node and planner-side sensors on one private channel, ticked in simulated time."""

    def __init__(self, channel, node_factory, tick_ms: int = 1):
        self.tx, self.rx, self.tap = channel(), channel(), channel()
        self.node: TractorTwinNode = node_factory(self.tx)
        self.sensors = TractorSensors(self.rx)
        self.tick_ms = tick_ms
        self.k = 0
        self.node.start(0.0)
        self.sensors.start(0.0)
        self.by_pgn: dict[int, int] = {}

    @property
    def now(self) -> float:
        return self.k * self.tick_ms / 1000.0

    def tick(self, *, twin: bool = True) -> float:
        t = self.now
        if twin:
            self.node.poll(t)
        self.sensors.poll(t)
        for m in drain(self.tap):
            self.by_pgn[pgn_of(m)] = self.by_pgn.get(pgn_of(m), 0) + 1
        self.k += 1
        return t


def test_rates_are_the_configured_periods(channel):
    bench = Bench(channel, lambda bus: TractorTwinNode.from_scenario(bus, "levelling", hitch_height_m=lambda t: 0.5))
    while bench.now < 10.0 - 1e-9:  # ticks at 0 … 9.999 s
        bench.tick()
    assert bench.by_pgn == {
        PGN_SLOPE_SENSOR_INFORMATION: 1000,  # 10 ms
        PGN_GROUND_DISTANCE: 500,  # 20 ms
        PGN_ROW_GUIDANCE: 100,  # the camera's 10 Hz
        PGN_WHEEL_BASED_SPEED: 100,  # 100 ms
    }
    c = bench.sensors.counters()
    assert c.frames == 1700 and c.errors == 0 and c.implausible == 0 and c.unavailable == 0


def test_other_periods_and_streams(channel):
    cfg = TractorNodeConfig(slope_period_s=0.02, ground_period_s=0.05, row_period_s=0.2, streams=("slope", "row"))
    bench = Bench(channel, lambda bus: TractorTwinNode(bus, ground_speed_m_s=1.0, config=cfg))
    while bench.now < 10.0 - 1e-9:
        bench.tick()
    assert bench.by_pgn == {PGN_SLOPE_SENSOR_INFORMATION: 500, PGN_ROW_GUIDANCE: 50}


def test_readings_decode_to_the_twins_truth(channel):
    scenario = load_scenario("terrain")  # undulating ground: pitch, pitch rate and ground distance vary
    sensors = TwinSensors(scenario.twin)
    twin = scenario.twin

    def height(t: float) -> float:
        return 0.6 + 0.1 * math.sin(t)  # the hitch moving

    bench = Bench(channel, lambda bus: TractorTwinNode(bus, sensors, hitch_height_m=height))
    checked = 0
    worst = dict.fromkeys(("roll", "pitch", "pitch_rate", "ground", "row"), 0.0)
    while bench.now < 10.0 - 1e-9:
        t = bench.tick()
        r = bench.sensors.readings()
        if r.roll.received_s != t:  # compare at the ticks a slope frame arrived
            continue
        st = twin.state(max(0.0, t - sensors.slope_latency_s))
        worst["roll"] = max(worst["roll"], abs(r.roll.value - st.roll_rad))
        worst["pitch"] = max(worst["pitch"], abs(r.pitch.value - st.pitch_rad))
        worst["pitch_rate"] = max(worst["pitch_rate"], abs(r.pitch_rate.value - st.pitch_rate_rad_s))
        assert r.slope_latency_s == pytest.approx(sensors.slope_latency_s)
        if r.ground_distance.received_s == t:
            worst["ground"] = max(worst["ground"], abs(r.ground_distance.value - twin.ground_distance_m(t, height(t))))
        if r.row_offset.received_s == t:
            worst["row"] = max(worst["row"], abs(r.row_offset.value - twin.row_measured_offset_m(t)))
        checked += 1
    assert checked == 1000
    assert worst["roll"] <= SSI_RES_RAD and worst["pitch"] <= SSI_RES_RAD and worst["pitch_rate"] <= SSI_RES_RAD
    assert worst["ground"] <= MM_01 and worst["row"] <= MM_01
    r = bench.sensors.readings()
    speed = twin.speed.speed_m_s(10.0)
    assert r.speed.value == pytest.approx(speed, abs=1e-3)
    assert r.distance.value == pytest.approx(twin.distance_m(r.distance.received_s), abs=1e-3)
    assert bench.sensors.distance_m() == r.distance.value
    assert r.unusable() == {}
    assert r.fresh(r.now_s, 0.1)


def test_row_offset_of_the_guidance_scenario(channel):
    scenario = load_scenario("guidance")  # 20 mm RMS row, 5 mm camera noise, 10 Hz
    bench = Bench(channel, lambda bus: TractorTwinNode(bus, TwinSensors(scenario.twin)))
    errs, values = [], []
    while bench.now < 10.0 - 1e-9:
        t = bench.tick()
        r = bench.sensors.readings()
        if r.row_offset.received_s == t:
            values.append(r.row_offset.value)
            errs.append(abs(r.row_offset.value - scenario.twin.row_measured_offset_m(t)))
    assert len(values) == 100 and max(errs) <= MM_01
    assert 0.005 < float(np.std(values)) < 0.06  # a moving row, not a constant
    assert bench.sensors.counters().implausible == 0


def test_levelling_roll_follows_the_side_slope(channel):
    # levelling.toml: cross slope 0.06 sin(2π s/111.1) + 0.04 sin(2π s/11.11 + 1), s = 2.2222 m/s · t
    def side_slope(t: float) -> float:
        s = 2.2222 * t
        return 0.06 * math.sin(2 * math.pi * s / 111.1) + 0.04 * math.sin(2 * math.pi * s / 11.11 + 1.0)

    bench = Bench(channel, lambda bus: TractorTwinNode.from_scenario(bus, "levelling"), tick_ms=10)
    worst, rolls = 0.0, []
    while bench.now < 45.0 - 1e-9:
        t = bench.tick()
        r = bench.sensors.readings()
        assert r.roll.received_s == t and r.roll.value is not None
        worst = max(worst, abs(r.roll.value - side_slope(max(0.0, t - 0.01))))  # the reported 10 ms latency
        assert abs(r.pitch.value) <= SSI_RES_RAD  # no grade, no undulation
        rolls.append(r.roll.value)
    assert worst <= SSI_RES_RAD
    assert max(rolls) > 0.06 and min(rolls) < -0.03  # the slopes swing both ways within 45 s (0.9 of the 111 m wave)
    # no ground sensor height given: the ground distance is "not available", not a number
    gd = bench.sensors.readings().ground_distance
    assert gd.value is None and gd.reason == "not available" and not gd.stale


def test_staleness_when_the_twin_stops(channel):
    bench = Bench(channel, lambda bus: TractorTwinNode.from_scenario(bus, "flat", hitch_height_m=lambda t: 0.4))
    while bench.now < 2.0 - 1e-9:
        bench.tick()
    r = bench.sensors.readings()
    assert r.unusable() == {} and r.ground_distance.value == pytest.approx(0.4, abs=MM_01)
    stopped = bench.now
    ages = {}
    while bench.now < stopped + 1.2:
        bench.tick(twin=False)
        r = bench.sensors.readings()
        for name in ("roll", "ground_distance", "row_offset", "speed", "distance"):
            if name not in ages and r.signal(name).stale:
                ages[name] = bench.now - stopped
    # stale limits 0.1 / 0.2 / 0.5 / 1 s after the last frame (sent up to one period before the stop)
    assert 0.09 <= ages["roll"] <= 0.12
    assert 0.18 <= ages["ground_distance"] <= 0.22
    assert 0.4 <= ages["row_offset"] <= 0.52
    assert 0.9 <= ages["speed"] <= 1.02 and 0.9 <= ages["distance"] <= 1.02
    r = bench.sensors.readings()
    assert not r.fresh(r.now_s, 0.5)
    assert r.roll.value is not None and not r.roll.usable  # the last value stays visible, flagged stale
    assert set(r.unusable()) == {"roll", "pitch", "pitch_rate", "ground_distance", "row_offset", "speed", "distance"}
    assert bench.sensors.distance_m() is None


def test_ground_distance_not_available_and_errors(channel):
    heights = iter([None, float("nan"), 20.0])  # no height, NaN, a height the twin refuses

    def height(t):
        return next(heights, 0.5)

    bench = Bench(channel, lambda bus: TractorTwinNode(bus, ground_speed_m_s=1.0, hitch_height_m=height))
    seen = []
    while bench.now < 0.1 - 1e-9:
        t = bench.tick()
        g = bench.sensors.readings().ground_distance
        if g.received_s == t:
            seen.append((g.value, g.reason))
    assert seen[:3] == [
        (None, "not available"),
        (None, "figure of merit: error"),
        (None, "figure of merit: error"),
    ]
    assert seen[3][0] == pytest.approx(0.5, abs=MM_01) and seen[3][1] is None
    assert bench.node.encode_errors == 0


def test_hitch_height_from_the_rigs_ecu(channel, model):
    with SimRig(model) as rig:
        rig.start()
        rig.run_until(0.2)
        height = hitch_height_from_ecu(rig.ecu, model, sensor_offset_m=-0.1)
        pose_z = model.pose(model.neutral).z
        expected = model.profile.geometry.pivot_height + pose_z - 0.1
        assert height(0.0) == pytest.approx(expected, abs=1e-3)  # the ECU rests at neutral
        bench = Bench(channel, lambda bus: TractorTwinNode(bus, ground_speed_m_s=0.0, hitch_height_m=height))
        bench.tick()
        g = bench.sensors.readings().ground_distance
        assert g.value == pytest.approx(height(0.0), abs=MM_01)  # flat ground: distance = height


def test_hitch_height_follows_the_pistons_after_a_rest(model):
    """The height function keeps the last piston positions' height (a hitch at rest costs no
    kinematics): after the pistons move it must be the new pose's height, every time."""
    from bridge.sim import CylinderECU

    ecu = CylinderECU(model.profile)
    height = hitch_height_from_ecu(ecu, model)
    base = model.profile.geometry.pivot_height

    def expected():
        q = [p.counts_to_si(float(c)) for p, c in zip(ecu.params, ecu.piston_counts(), strict=True)]
        return base + model.pose(q).z

    first = height(0.0)
    assert height(0.01) == first == pytest.approx(expected(), abs=1e-12)  # at rest: the same value
    ref = ecu.measurement_counts() + np.array([60, 0, 0, 0, 0])  # raise the lift
    for k in range(150):
        ecu.set_reference(ref, 0.01 * k)
        ecu.step(0.01 * (k + 1))
        assert height(0.0) == pytest.approx(expected(), abs=1e-12)
    assert height(0.0) > first + 0.01


def test_runs_in_real_time_under_the_runner(channel):
    tx, rx = channel(), channel()
    node = TractorTwinNode.from_scenario(tx, "levelling", hitch_height_m=lambda t: 0.5)
    sensors = TractorSensors(rx)
    with RealtimeRunner(sensors, max_wait_s=0.02), RealtimeRunner(node, max_wait_s=0.02) as runner:
        for _ in range(100):  # up to 5 s on a loaded machine
            if sensors.readings().unusable() == {} and sensors.counters().frames >= 20:
                break
            runner.wait(0.05)
        r = sensors.readings()
    assert r.unusable() == {}, r.unusable()
    assert abs(r.roll.value) < 0.11 and r.ground_distance.value == pytest.approx(0.5, abs=0.01)
    assert sensors.counters().errors == 0


def test_the_distance_wrap_is_one_value():
    from bridge.link.tractor_sensors import DISTANCE_WRAP_M as LINK_WRAP
    from bridge.service.odometer import DISTANCE_WRAP_M as ODOMETER_WRAP

    # the largest valid 32-bit J1939 value 0xFAFFFFFF at 1 mm/bit
    assert DISTANCE_WRAP_M == LINK_WRAP == ODOMETER_WRAP == pytest.approx(0xFAFFFFFF * 0.001, abs=1e-9)
