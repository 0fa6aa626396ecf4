"""The planner-side CAN link: reference checks and conversion, stream rate, measured state,
stale-measurement stop, malformed/foreign frames, ECU restart, heartbeat and address faults,
bus errors."""

import math
import uuid

import can
import numpy as np
import pytest

from bridge.isobus.address_claim import ClaimState, planner_name
from bridge.isobus.codec import (
    AddressClaimed,
    Heartbeat,
    PositionCounts,
    PositionMeasurement,
    RearHitchStatus,
    decode_frame,
    encode,
)
from bridge.isobus.j1939 import PGN_POSITION_REFERENCE, decode_id
from bridge.link.can_link import CanLink
from bridge.link.state import LinkConfig, LinkFaultError, ReferenceRefused
from bridge.sim.move import SimRig, SimSettings
from planner.model.exact_inverse import ExactInverse
from planner.model.sensors import SensorScaling

TICK = 0.001


def drain(bus):
    out = []
    while (f := bus.recv(timeout=0.0)) is not None:
        out.append(f)
    return out


def references_on(frames):
    return [decode_frame(f).payload for f in frames if decode_id(f.arbitration_id).pgn == PGN_POSITION_REFERENCE]


@pytest.fixture
def tap(rig):
    bus = can.Bus(interface="virtual", channel=rig.channel)
    yield bus
    bus.shutdown()


def test_reference_counts_hand_computed(rig, model):
    counts = rig.link.check_reference([0.300, 0.630, 0.800, 0.540, 0.540])
    # thesis tables 3-1, 3-2: lift 26 + (0.300 + 0.223) / 0.886 * 229 = 161.18 -> 161;
    # tilt 26 + 0.050 / 0.150 * 891 = 323; top 26 + 0.145 / 0.250 * 229 = 158.82 -> 159;
    # left 30 + 0.040 / 0.080 * 480 = 270; right 26 + 0.040 / 0.075 * 477 = 280.4 -> 280
    assert counts == PositionCounts(lift=161, tilt=323, top=159, left=270, right=280)


@pytest.mark.parametrize(
    "index, delta, limit",
    [
        (0, +0.5, "stroke:lift:max"),
        (0, -0.5, "stroke:lift:min"),
        (1, +0.2, "stroke:tilt:max"),
        (2, -0.3, "stroke:top:min"),
        (3, +0.1, "stroke:left:max"),
        (4, -0.1, "stroke:right:min"),
    ],
)
def test_out_of_stroke_reference_is_refused_by_name_and_never_sent(rig, tap, model, index, delta, limit):
    q = model.neutral.copy()
    q[index] += delta
    with pytest.raises(ReferenceRefused) as err:
        rig.link.send_reference(q, rig.next_tick_s)
    assert limit in str(err.value) or "cannot take" in str(err.value)
    rig.run_until(rig.now_s + 0.2)
    assert references_on(drain(tap)) == []
    assert rig.link.counters.references_refused == 1 and not rig.link.streaming


def test_a_reference_checked_then_sent_is_evaluated_once_and_a_refused_one_every_time(rig, model, monkeypatch):
    """The controller checks the reference it will send (feed-forward) and send_reference checks it
    again: the second check of the same values answers the first's counts without evaluating the
    kinematics again; other values, and refused ones, are evaluated afresh."""
    calls = []
    features = model.features

    def counted(q):
        calls.append(np.array(q, float))
        return features(q)

    monkeypatch.setattr(model, "features", counted)
    link = rig.link
    q = model.neutral.copy()
    counts = link.check_reference(q)
    assert link.send_reference(q.copy(), rig.next_tick_s) == counts and len(calls) == 1
    q2 = q + [0.01, 0.0, 0.0, 0.0, 0.0]
    assert link.check_reference(q2) != counts and len(calls) == 2
    assert link.check_reference(list(q)) == counts and len(calls) == 3  # the last one was q2
    bad = q.copy()
    bad[0] += 0.5
    for n in (4, 5):
        with pytest.raises(ReferenceRefused, match="stroke:lift:max|cannot take"):
            link.check_reference(bad)
        assert len(calls) == n


@pytest.mark.parametrize("bad", [[0.2, 0.63, 0.75, 0.54], [math.nan, 0.63, 0.75, 0.54, 0.54], "lift", None])
def test_malformed_reference_input_is_refused(rig, bad):
    with pytest.raises(ReferenceRefused):
        rig.link.send_reference(bad, rig.next_tick_s)


def test_random_references_only_within_limits_reach_the_bus(rig, tap, model):
    """Invariant over random actuator vectors (fixed seed): every reference on the bus is one the
    hard limits accepted, inside the calibrated span; refused ones never appear."""
    rng = np.random.default_rng(6)
    scaling = SensorScaling(model.profile)
    accepted, refused = set(), 0
    for _ in range(120):
        q = model.lower - 0.1 * (model.upper - model.lower) + 1.2 * (model.upper - model.lower) * rng.random(5)
        try:
            counts = rig.link.send_reference(q, rig.next_tick_s)
        except ReferenceRefused:
            refused += 1
        else:
            accepted.add(counts.as_tuple())
            assert np.all(q >= model.lower) and np.all(q <= model.upper)
        rig.run_until(rig.now_s + 0.02)
    on_bus = {r.as_tuple() for r in references_on(drain(tap))}
    assert len(accepted) > 10 and refused > 10  # both branches exercised
    assert on_bus <= accepted and len(on_bus) >= len(accepted) - 1
    for counts in on_bus:
        assert all(scaling.counts_min[i] <= c <= scaling.counts_max[i] for i, c in enumerate(counts))


def test_stream_rate_is_the_control_rate(rig, tap, model):
    t0 = rig.next_tick_s
    rig.link.send_reference(model.neutral, t0)
    rig.run_until(t0 + 1.0, every_tick=lambda t: rig.link.send_reference(model.neutral, t))  # caller at 1 kHz
    refs = references_on(drain(tap))
    assert len(refs) == 51  # 50 Hz: t0 + 0.02 k, k = 0..50 inclusive
    assert rig.node.counters.references == 51


def test_the_link_holds_once_it_re_sends_an_older_reference_twice_and_not_while_references_come(rig, model):
    """``holding``: the stream re-sent a reference handed over before the previous frame, twice in a row
    (the controller at rest after a move). A caller at the control rate, also a few milliseconds late
    now and then, is never taken for holding; a new reference ends holding at once; no stream, no
    holding."""
    link = rig.link
    assert not link.streaming and not link.holding
    t0 = rig.next_tick_s
    rng = np.random.default_rng(3)
    held: list[bool] = []
    for k in range(50):  # a 50 Hz caller, 0..8 ms behind its slot
        t = t0 + 0.02 * k + 0.001 * int(rng.integers(0, 9))
        rig.run_until(t)
        link.send_reference(model.neutral, t)
        held.append(link.holding)
    assert link.streaming and not any(held)
    t_last = rig.now_s
    rig.run_until(t_last + 0.025)  # one frame re-sent: a late cycle, not yet holding
    assert not link.holding
    rig.run_until(t_last + 0.065)  # the link re-sent the reference twice in a row
    assert link.holding
    link.send_reference(model.neutral, rig.now_s)
    assert not link.holding
    link.stop_motion()
    assert not link.streaming and not link.holding


def _stream_log(rig, tap, calls, until_s):
    """Run the rig tick by tick to ``until_s``; ``calls``: {tick time: actuators} sent (before that tick's
    polls, as a control cycle does). Returns [(tick time, counts tuple)] of every reference frame."""
    log = []

    def each(t):
        q = calls.get(round(t, 6))
        if q is not None:
            rig.link.send_reference(q, t)

    while rig.now_s < until_s - 1e-9:
        rig.run_until(rig.next_tick_s, every_tick=each)
        log += [(round(rig.now_s, 6), r.as_tuple()) for r in references_on(drain(tap))]
    return log


def _two_references(model):
    """Two references a few counts apart (each call alternates, so each frame says which call it carries)."""
    a = np.array(model.neutral, float)
    b = a.copy()
    b[1] += 0.004  # the tilt cylinder 4 mm longer
    return a, b


def test_a_fresh_reference_goes_at_once_even_just_after_its_slot(rig, tap, model):
    """A 50 Hz caller a few ms behind its slot (its cycle's own jitter): each reference goes on the bus
    when it is sent. On the old code the stream repeated the last reference at the slot first, and the
    fresh one waited a whole period (latency 13-20 ms instead of 0; bimodal service latency, #15)."""
    a, b = _two_references(model)
    counts = {tuple(rig.link.check_reference(a).as_tuple()): "a", tuple(rig.link.check_reference(b).as_tuple()): "b"}
    t0 = round(rig.next_tick_s, 6)
    rng = np.random.default_rng(15)
    jitter_ms = rng.integers(0, 9, size=50)  # 0..8 ms late
    calls, expect = {}, []
    for k, j in enumerate(jitter_ms):
        t = round(t0 + 0.02 * k + 0.001 * int(j), 6)
        calls[t] = a if k % 2 == 0 else b
        expect.append((t, "a" if k % 2 == 0 else "b"))
    log = _stream_log(rig, tap, calls, t0 + 1.0)
    fresh = {}  # the first frame of each call's value after the call
    for t, name in expect:
        fresh[t] = next(ts for ts, c in log if ts >= t - 1e-9 and counts[c] == name)
    delays_ms = [1000 * (fresh[t] - t) for t, _ in expect]
    assert max(delays_ms) <= 1e-6, delays_ms
    assert len(log) == 50  # nothing repeated in between: one frame per call


def test_a_fresh_reference_may_come_half_a_period_early_and_a_faster_caller_waits(rig, tap, model):
    a, b = _two_references(model)
    t0 = round(rig.next_tick_s, 6)
    # 3 ms early for its slot: goes at once; then one 5 ms after that (faster than the rate): waits for its slot
    log = _stream_log(rig, tap, {t0: a, round(t0 + 0.017, 6): b, round(t0 + 0.022, 6): a}, t0 + 0.1)
    times = [t for t, _ in log]
    assert times[:3] == [t0, round(t0 + 0.017, 6), round(t0 + 0.030, 6)], times  # slot t0+0.04, P/2 early
    ref_a = rig.link.check_reference(a).as_tuple()
    assert log[2][1] == ref_a


def test_the_stream_never_exceeds_its_rate_and_never_pauses_beyond_two_periods(rig, tap, model):
    """Property over random call times (bursts, gaps, stalls): frames at least P/2 apart and k + 1 frames
    span at least (k - 1) P - P/2 (at most floor(T/P + 1/2) + 2 in any window of T seconds); while
    streaming, at most 2 P apart (a frame sent P/2 early, then a repetition P/2 late), well inside the
    ECU's 100 ms watchdog."""
    a, b = _two_references(model)
    rng = np.random.default_rng(1939)
    t0 = round(rig.next_tick_s, 6)
    t, k, calls = t0, 0, {}
    while t < t0 + 2.0:
        calls[round(t, 6)] = a if k % 2 == 0 else b
        k += 1
        t += 0.001 * int(rng.choice([1, 2, 5, 10, 19, 20, 21, 35, 60]))
    log = _stream_log(rig, tap, calls, t0 + 2.2)
    times = np.array([ts for ts, _ in log])
    p = 0.02
    assert len(times) > 60
    for i in range(len(times)):
        for j in range(i + 1, len(times)):
            assert times[j] - times[i] >= (j - i - 1) * p - p / 2 - 1e-9, (i, j, times[i], times[j])
    assert np.min(np.diff(times)) >= p / 2 - 1e-9
    assert np.max(np.diff(times)) <= 2 * p + 1e-9


def test_a_late_frame_or_a_restart_never_sends_within_half_a_period_of_the_last_frame(rig, tap, model):
    """Review findings: a repetition polled 9.9 ms late let the next fresh reference out 0.1 ms later (3
    frames in 10.1 ms), and a stop and restart sent at once whatever went just before."""
    a, b = _two_references(model)
    t0 = round(rig.next_tick_s, 6)
    link = rig.link
    sent = []

    def step(fn, t):
        fn(t)
        sent.extend(t for _ in references_on(drain(tap)))

    step(lambda t: link.send_reference(a, t), t0)  # slot t0 + P next
    step(link.poll, t0 + 0.0399)  # the repetition, 9.9 ms late
    step(lambda t: link.send_reference(b, t), t0 + 0.0400)  # held: within P/2 of the repetition
    step(link.poll, t0 + 0.0498)
    step(link.poll, t0 + 0.0499)  # P/2 after the repetition: goes
    step(lambda t: (link.stop_motion(), link.send_reference(a, t)), t0 + 0.0505)  # restart: held
    step(link.poll, t0 + 0.0598)
    step(link.poll, t0 + 0.0599)  # P/2 after the last frame
    assert [round(t - t0, 4) for t in sent] == [0.0, 0.0399, 0.0499, 0.0599], sent


def test_stream_rate_configurable(model):
    with SimRig(model, SimSettings(link=LinkConfig(control_rate_hz=20.0))) as rig:
        tap = can.Bus(interface="virtual", channel=rig.channel)
        rig.start()
        rig.run_until(0.4)
        t0 = rig.next_tick_s
        rig.link.send_reference(model.neutral, t0)
        rig.run_until(t0 + 0.999)
        assert len(references_on(drain(tap))) == 20
        tap.shutdown()


def test_measured_state_is_forward_kinematics_of_the_quantised_readings(rig, model):
    st = rig.link.latest_state()
    ecu = rig.ecu
    c = ecu.measurement_counts()
    s = SensorScaling(model.profile)
    # the lift goes through the rear hitch position (0.4 %/bit) and comes back as its count
    assert st.lift_fraction == round(250 * (c[0] - 26) / 229) / 250
    counts = np.array(c, dtype=float)
    q = s.si_min + (counts - s.counts_min) * s.resolution
    assert np.allclose(st.actuators.as_array(), q, atol=1e-12)
    assert np.allclose(st.pose.as_array(), model.forward(q).pose.as_array(), atol=1e-12)
    truth = model.forward(
        np.array([p.counts_to_si(x) for p, x in zip(ecu.params, ecu.piston_counts(), strict=True)])
    ).pose
    # quantisation limit: half an AD count; lift 3.87 mrad/count ~ 3.7 mm of z per count
    assert abs(st.pose.z - truth.z) < 0.002 and abs(st.pose.x - truth.x) < 0.002
    assert st.system.controllers_on and st.system.watchdog_tripped


def test_stale_measurement_stops_motion_and_needs_a_fresh_command(rig, tap, model):
    link = rig.link
    goal = ExactInverse(model)(0.0, 0.25, 0.0, 0.0)
    link.send_reference(goal, rig.next_tick_s)
    rig.run_until(1.0)
    assert link.streaming
    t_last = link.latest_state().measurement_t_s
    rig.ecu_paused = True  # the ECU falls silent
    while not link.faults.any:
        rig.tick()
    assert link.faults.stale_measurement and not link.streaming
    assert 0.2 < rig.now_s - t_last <= 0.2 + 1.5 * TICK  # > 200 ms, seen at the next 1 ms poll
    drain(tap)
    rig.run_until(rig.now_s + 0.1)
    assert references_on(drain(tap)) == []
    with pytest.raises(
        LinkFaultError, match=r"no valid cylinder positions \(0xFF22\) from the cylinder ECU \(address 169\)"
    ):
        link.send_reference(goal, rig.next_tick_s)
    rig.ecu_paused = False
    rig.run_until(rig.now_s + 0.5)  # the ECU speaks again: no motion without a command
    assert references_on(drain(tap)) == [] and not link.streaming
    assert not rig.ecu.valve_commands().any()
    with pytest.raises(LinkFaultError, match="heartbeat"):  # ISO 11783-7: 8 good heartbeats to recover
        link.send_reference(goal, rig.next_tick_s)
    rig.run_until(rig.now_s + 0.4)
    link.send_reference(goal, rig.next_tick_s)  # a fresh command re-arms
    rig.run_until(rig.now_s + 0.1)
    assert link.streaming and not link.faults.any and len(references_on(drain(tap))) == 5
    assert link.counters.faults_raised == 2  # stale, then the heartbeat timeout


def test_malformed_foreign_and_unknown_frames_are_counted_not_used(rig, model):
    link = rig.link
    raw = can.Bus(interface="virtual", channel=rig.channel)
    c = [int(v) for v in rig.ecu.measurement_counts()]  # lift, tilt, top, left, right
    sys_state = rig.ecu.system_state()
    good = PositionMeasurement(c[1] + 7, c[2], c[4], c[3], sys_state)
    pm = encode(good, source=169)
    c0 = link.counters
    raw.send(can.Message(arbitration_id=pm.arbitration_id, is_extended_id=True, data=bytes(pm.data)[:6]))  # DLC 6
    raw.send(
        can.Message(arbitration_id=pm.arbitration_id, is_extended_id=True, data=b"\xff\xbf" + bytes(pm.data)[2:])
    )  # tilt = 1022, the error code -> unavailable
    raw.send(encode(PositionMeasurement(c[1], c[2], 600, c[3], sys_state), source=169))  # right 600 > 503
    raw.send(encode(good, source=0x42))  # not the ECU
    raw.send(can.Message(arbitration_id=(6 << 26) | (0xFE49 << 8) | 0x80, is_extended_id=True, data=b"\xff" * 8))
    raw.send(can.Message(arbitration_id=0x100, is_extended_id=False, data=b"\x00"))
    raw.send(can.Message(is_error_frame=True))
    raw.send(encode(RearHitchStatus(position=None), source=169))
    raw.send(pm)  # the one valid frame, last
    link.poll(rig.now_s)
    raw.shutdown()
    c1 = link.counters
    d = {k: getattr(c1, k) - getattr(c0, k) for k in c1.as_dict()}
    assert (d["malformed"], d["unknown_pgn"], d["bus_errors"], d["foreign"]) == (1, 1, 1, 2)
    assert (d["unavailable_readings"], d["rejected_readings"], d["measurements_rx"]) == (2, 1, 3)
    assert not link.faults.any  # unknown ISOBUS traffic and single bad frames are not faults
    status = link.status(rig.now_s)
    assert "DLC 6" in status.last_malformed and "rear hitch position" in status.last_reading_problem
    assert link.latest_state().counts[1] == c[1] + 7  # only the valid frame was used
    rig.run_until(rig.now_s + 0.011)
    assert link.latest_state().counts[1] == c[1]  # and the ECU's next frame replaces it


def test_ecu_restart_is_detected_and_the_old_reference_never_resumes(rig, model):
    link, node, ecu = rig.link, rig.node, rig.ecu
    goal = ExactInverse(model)(0.0, 0.25, 0.0, 0.0)
    link.send_reference(goal, rig.next_tick_s)
    rig.run_until(1.0)
    node.restart(rig.now_s)
    rig.run_until(2.0)
    f = link.faults
    assert f.ecu_restart and not link.streaming
    assert any("251" in r or "restart counter" in r for r in f.reasons)
    assert ecu.reference_counts() is None and not ecu.valve_commands().any()
    rig.run_until(2.5)
    assert ecu.reference_counts() is None  # still nothing: the stream did not resume by itself
    link.send_reference(goal, rig.next_tick_s)
    rig.run_until(2.6)
    assert link.streaming and not link.faults.any
    assert list(ecu.reference_counts()) == list(link.check_reference(goal).as_tuple())


def test_assembler_spots_restarts_in_the_system_state_byte(model):
    """Restart counter change and the no-reference bit reappearing, each on its own (no heartbeat)."""
    from bridge.link.state import MeasurementAssembler

    bumps = {}
    rx = MeasurementAssembler(
        model,
        SensorScaling(model.profile),
        LinkConfig(),
        lambda **d: [bumps.__setitem__(k, bumps.get(k, 0) + v) for k, v in d.items()],
    )
    readings = (323, 141, 265, 270)  # tilt, top, right, left
    m = lambda state: PositionMeasurement(*readings, system_state=state)  # noqa: E731
    assert rx.on_measurement(m(0b1011), 0.00) is None  # no reference yet, restart counter 0
    assert rx.on_measurement(m(0b0001), 0.01) is None  # reference latched
    assert "no-reference" in rx.on_measurement(m(0b1001), 0.02)  # lost it without a counter change
    assert rx.on_measurement(m(0b1001), 0.03) is None  # reported once
    assert "restart counter 0 -> 1" in rx.on_measurement(m(0b0001_1001), 0.04)
    assert rx.state is None and bumps["measurements_rx"] == 5  # no lift yet: no state
    rx.on_hitch_status(RearHitchStatus(position=0.504), 0.05)
    assert rx.state is not None and rx.state.lift_fraction == 0.504
    # 0.04 s -> 0.50 s at 10 ms: 46 periods, 45 frames missing
    assert rx.on_measurement(m(0b0001_1001), 0.5) is None and bumps.get("dropped_measurements") == 45


@pytest.mark.parametrize("bus_timestamps", [True, False])
def test_frames_read_together_are_counted_as_dropped_only_from_their_stamps(model, bus_timestamps):
    """A loop that reads the bus only at its deadlines (RealtimeRunner's ``prompt``) takes the ECU's
    10 ms frames two at a time, both at the read time. With bus stamps the gaps come from the stamps:
    none missing, and a real gap (one frame lost) counted once. Before, the read times' 20 ms steps were
    counted as one dropped frame per read (9 for these 10 reads). Without stamps (a simulated clock)
    the read times are all there is."""
    from bridge.link.state import MeasurementAssembler

    bumps: dict[str, int] = {}
    rx = MeasurementAssembler(
        model,
        SensorScaling(model.profile),
        LinkConfig(bus_timestamps=bus_timestamps),
        lambda **d: [bumps.__setitem__(k, bumps.get(k, 0) + v) for k, v in d.items()],
    )
    m = PositionMeasurement(323, 141, 265, 270, system_state=0b0001)
    wall0 = 1.7e9  # bus stamps are wall-clock seconds
    for read in range(10):
        now = 0.02 * (read + 1)
        for k in (2 * read, 2 * read + 1):
            rx.on_measurement(m, now, wall0 + 0.01 * k)
            rx.on_hitch_status(RearHitchStatus(position=0.5), now, wall0 + 0.01 * k)
    # stamped: none missing, then the lost frame of 0.20, then nothing (an unstamped frame is never
    # measured against a stamp); read times: 9 per 20 ms read, then 0.20 -> 0.24 s (3), 0.24 -> 0.26 s (1)
    expected = (0, 1, 1) if bus_timestamps else (9, 12, 13)
    assert (bumps.get("dropped_measurements", 0), bumps.get("dropped_hitch_status", 0)) == (expected[0],) * 2
    rx.on_measurement(m, 0.24, wall0 + 0.21)  # 0.19 -> 0.21 s: the frame of 0.20 s is missing
    assert bumps.get("dropped_measurements", 0) == expected[1]
    rx.on_measurement(m, 0.26, None)
    assert bumps.get("dropped_measurements", 0) == expected[2]
    if bus_timestamps:  # the bus's wall clock steps (NTP, a GNSS time fix): the read times count
        rx.on_measurement(m, 0.27, wall0 + 0.22)
        rx.on_measurement(m, 0.28, wall0 + 1e5)  # 10 ms later by the read times: nothing missing
        rx.on_measurement(m, 0.30, wall0 - 50.0)  # a step back: 20 ms by the read times, one missing
        assert bumps.get("dropped_measurements", 0) == expected[2] + 1


def test_missing_and_error_heartbeats_stop_motion(model):
    """A hand-driven 'ECU' that sends measurements but no heartbeat, then heartbeat 254."""
    ch = f"hb-{uuid.uuid4().hex}"
    bus, ecu_bus = (can.Bus(interface="virtual", channel=ch) for _ in range(2))
    link = CanLink(model, bus)
    counts = SensorScaling(model.profile).to_counts(model.neutral)

    def ecu_frames(t, heartbeat=None):
        tilt, top, left, right = (int(c) for c in counts[1:])
        ecu_bus.send(encode(PositionMeasurement(tilt, top, right, left, 1), source=169))
        ecu_bus.send(encode(RearHitchStatus(position=0.5), source=169))
        if heartbeat is not None:
            ecu_bus.send(encode(Heartbeat(heartbeat), source=169))

    link.start(0.0)
    t, k = 0.0, 0
    while t < 0.25 + 0.3:
        k += 1
        t = k * 0.01
        ecu_frames(t)
        link.poll(t)
    assert not link.faults.any
    ecu_frames(t + 0.01)
    link.poll(t + 0.01)  # 0.31 s after the claim without a heartbeat
    assert link.faults.ecu_heartbeat
    seq = 251
    for j in range(10):  # heartbeats arrive: a fresh command is accepted
        ecu_frames(t + 0.02 + 0.1 * j, heartbeat=seq)
        link.poll(t + 0.02 + 0.1 * j)
        seq = 0 if seq == 251 else seq + 1
    t = t + 0.02 + 0.9
    link.send_reference(model.neutral, t)
    assert link.streaming
    ecu_frames(t + 0.01, heartbeat=254)
    link.poll(t + 0.01)
    assert link.faults.ecu_heartbeat and not link.streaming
    assert any("sender error" in r for r in link.faults.reasons)
    bus.shutdown()
    ecu_bus.shutdown()


def test_a_silent_heartbeat_fault_says_how_long_against_what_limit_and_the_last_counter(model):
    """An incident investigator's report: the fault said "ECU heartbeat timeout" alone, where the stale
    measurement's says its age and limit."""
    ch = f"hb-silent-{uuid.uuid4().hex}"
    bus, ecu_bus = (can.Bus(interface="virtual", channel=ch) for _ in range(2))
    link = CanLink(model, bus)
    counts = SensorScaling(model.profile).to_counts(model.neutral)
    tilt, top, left, right = (int(c) for c in counts[1:])
    link.start(0.0)
    seq, t = 251, 0.0
    for k in range(1, 60):  # measurements every 10 ms, heartbeats every 100 ms
        t = k * 0.01
        ecu_bus.send(encode(PositionMeasurement(tilt, top, right, left, 1), source=169))
        ecu_bus.send(encode(RearHitchStatus(position=0.5), source=169))
        if k % 10 == 0:
            ecu_bus.send(encode(Heartbeat(seq), source=169))
            last, seq = seq, 0 if seq == 251 else seq + 1
        link.poll(t)
    for k in range(60, 110):  # the heartbeats stop, the measurements go on
        t = k * 0.01
        ecu_bus.send(encode(PositionMeasurement(tilt, top, right, left, 1), source=169))
        ecu_bus.send(encode(RearHitchStatus(position=0.5), source=169))
        link.poll(t)
    assert link.faults.ecu_heartbeat
    said = [r for r in link.faults.reasons if "heartbeat" in r]
    assert said and said[0].startswith("ECU heartbeat timeout: none for 0."), said
    assert f"s (limit {link.config.heartbeat_timeout_s:g} s); last counter {last}" in said[0], said
    bus.shutdown()
    ecu_bus.shutdown()


def test_a_frozen_heartbeat_counter_stops_motion_and_clears_once_in_sequence_again(model):
    """An ECU whose main loop hangs while its CAN controller keeps re-sending the last heartbeat: the
    counter repeats every 100 ms. ISO 11783-7 calls that a communication error and docs/faults.md says
    ``ecu_heartbeat`` covers "out of sequence"; before, only silence, 254 and 255 raised it and a motion
    already streaming went on. Its cause is gone after 8 heartbeats in sequence."""
    ch = f"hbfrozen-{uuid.uuid4().hex}"
    bus, ecu_bus = (can.Bus(interface="virtual", channel=ch) for _ in range(2))
    link = CanLink(model, bus)
    tilt, top, left, right = (int(c) for c in SensorScaling(model.profile).to_counts(model.neutral)[1:])
    seq = [251]

    def ecu_sends(k: int, *, frozen: bool = False) -> None:
        ecu_bus.send(encode(PositionMeasurement(tilt, top, right, left, 1), source=169))
        ecu_bus.send(encode(RearHitchStatus(position=0.5), source=169))
        if k % 10 == 0:  # every 100 ms
            ecu_bus.send(encode(Heartbeat(seq[0]), source=169))
            if not frozen:
                seq[0] = 0 if seq[0] in (250, 251) else seq[0] + 1

    link.start(0.0)
    for k in range(1, 101):  # 1 s healthy
        ecu_sends(k)
        link.poll(k * 0.01)
    assert not link.faults.any
    link.send_reference(model.neutral, 1.0)
    assert link.streaming
    for k in range(101, 131):  # the counter repeats for 0.3 s while references stream
        ecu_sends(k, frozen=True)
        link.poll(k * 0.01)
    assert link.faults.ecu_heartbeat and not link.streaming
    assert any("sequence error" in r for r in link.faults.reasons), link.faults.reasons
    assert "ecu_heartbeat" in link.fault_causes(1.3)
    with pytest.raises(LinkFaultError, match="sequence error"):  # no fresh command while it lasts
        link.send_reference(model.neutral, 1.3)
    for k in range(131, 251):  # in sequence again for 1.2 s: 12 heartbeats (8 needed)
        ecu_sends(k)
        link.poll(k * 0.01)
    assert not link.fault_causes(2.5)
    link.send_reference(model.neutral, 2.5)  # the latch lifts with a fresh command once the cause is gone
    assert link.streaming and not link.faults.any
    bus.shutdown()
    ecu_bus.shutdown()


def test_two_ecus_on_one_address_are_named_as_a_possible_cause_of_the_sequence_error(model):
    """A second ``hitch ecu-sim`` left running on the hub: two heartbeat counters interleave from address 169.
    The fault said only "ECU heartbeat sequence error; last counter 17"; now it names the likely cause. A
    single jump of one ECU's counter does not."""

    def run(counters: list[int]) -> list[str]:
        ch = f"hbtwo-{uuid.uuid4().hex}"
        bus, ecu_bus = (can.Bus(interface="virtual", channel=ch) for _ in range(2))
        link = CanLink(model, bus)
        tilt, top, left, right = (int(c) for c in SensorScaling(model.profile).to_counts(model.neutral)[1:])
        link.start(0.0)
        for k in range(1, 10 * len(counters) + 1):
            ecu_bus.send(encode(PositionMeasurement(tilt, top, right, left, 1), source=169))
            ecu_bus.send(encode(RearHitchStatus(position=0.5), source=169))
            if k % 10 == 0:
                ecu_bus.send(encode(Heartbeat(counters[k // 10 - 1]), source=169))
            link.poll(k * 0.01)
        bus.shutdown()
        ecu_bus.shutdown()
        return [r for r in link.faults.reasons if "heartbeat" in r]

    one = list(range(0, 20))
    two = [v for pair in zip(range(0, 20), range(100, 120), strict=True) for v in pair]  # two ECUs, 50 ms apart
    jump = list(range(0, 10)) + list(range(40, 50))
    assert run(one) == []
    said = run(two)
    assert said and all("possibly two nodes sending with source address 169" in r for r in said), said
    said = run(jump)
    assert said and not any("two nodes" in r for r in said), said


@pytest.mark.parametrize("bus_timestamps", [True, False])
def test_a_stall_of_the_planner_alone_is_not_an_ecu_heartbeat_fault(model, bus_timestamps):
    """The ECU keeps its 100 ms heartbeat while the planner's thread stalls for 0.4 s; the frames wait in
    the bus and are all read at once. Judged by the frames' timestamps (the real-time service's setting)
    the ECU was on time: no fault. Judged by read times (before: the only way) it was 'late'. A real
    0.4 s silence of the ECU, stamped so, is a fault either way."""
    ch = f"hbstall-{uuid.uuid4().hex}"
    bus = can.Bus(interface="virtual", channel=ch)
    ecu_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)  # stamps: the send times
    link = CanLink(model, bus, LinkConfig(bus_timestamps=bus_timestamps))
    tilt, top, left, right = (int(c) for c in SensorScaling(model.profile).to_counts(model.neutral)[1:])
    seq = [251]

    def ecu_sends(t, heartbeat=None):  # None: on the 100 ms grid
        frames = [
            encode(PositionMeasurement(tilt, top, right, left, 1), source=169),
            encode(RearHitchStatus(position=0.5), source=169),
        ]
        if heartbeat or (heartbeat is None and round(t * 100) % 10 == 0):
            frames.append(encode(Heartbeat(seq[0]), source=169))
            seq[0] = 0 if seq[0] in (250, 251) else seq[0] + 1
        for f in frames:
            f.timestamp = 1000.0 + t  # another clock's origin: only its differences count
            ecu_bus.send(f)

    link.start(0.0)
    for k in range(1, 101):  # 1 s, polled every 10 ms: healthy
        ecu_sends(k * 0.01)
        link.poll(k * 0.01)
    assert not link.faults.any and not link.fault_causes(1.0)
    for k in range(101, 141):  # the planner stalls 0.4 s; the ECU goes on
        ecu_sends(k * 0.01)
    link.poll(1.40)
    assert link.faults.ecu_heartbeat is not bus_timestamps, link.faults.reasons
    if not bus_timestamps:
        bus.shutdown()
        ecu_bus.shutdown()
        return
    for k in range(141, 161):
        ecu_sends(k * 0.01)
        link.poll(k * 0.01)
    for k in range(161, 201):  # now the ECU is silent for 0.4 s while the planner stalls
        ecu_sends(k * 0.01, heartbeat=False)
    ecu_sends(2.01, heartbeat=True)  # 0.41 s after the last one, by its own timestamp
    link.poll(2.01)
    assert link.faults.ecu_heartbeat, "a real 0.4 s silence of the ECU's heartbeat must be a fault"
    bus.shutdown()
    ecu_bus.shutdown()


def test_lost_address_claim_stops_the_link(rig, model):
    rival = can.Bus(interface="virtual", channel=rig.channel)
    rig.link.send_reference(model.neutral, rig.next_tick_s)
    rival.send(encode(AddressClaimed(planner_name(identity_number=0).value), source=166))  # lower NAME
    rig.tick()
    rival.shutdown()
    assert rig.link._claimer.state is ClaimState.CANNOT_CLAIM  # noqa: SLF001
    assert rig.link.faults.address_lost and not rig.link.streaming
    with pytest.raises(LinkFaultError, match="not claimed"):
        rig.link.send_reference(model.neutral, rig.next_tick_s)


class _BrokenBus(can.BusABC):
    """Sends fail (e.g. bus-off); receives nothing."""

    def __init__(self):
        super().__init__(channel="broken")

    def send(self, msg, timeout=None):
        raise can.CanOperationError("bus off")

    def _recv_internal(self, timeout):
        return None, False


def test_failed_sends_are_counted_and_raise_the_bus_fault(model):
    link = CanLink(model, _BrokenBus(), own_bus=True)
    link.start(0.0)
    for k in range(1, 40):
        link.poll(k * 0.01)
    c = link.counters
    assert c.tx_errors >= 3 and c.frames_tx == 0
    assert link.faults.bus_error
    link.close()


class _GoneHubBus(_BrokenBus):
    """A remote hub that went away: the websocket's send raises the socket's own error."""

    def send(self, msg, timeout=None):
        raise BrokenPipeError(32, "Broken pipe")


def test_a_send_to_a_hub_that_went_away_is_a_bus_fault_naming_it_not_an_internal_error(model):
    """A field trial: the hub killed mid-motion; the send raised BrokenPipeError through the control cycle, and the
    operator read "internal error: BrokenPipeError" (fault ``internal``). Now counted as a failed send: the bus
    fault says what the sends raised."""
    link = CanLink(model, _GoneHubBus(), own_bus=True)
    link.start(0.0)
    for k in range(1, 40):
        link.poll(k * 0.01)
    assert link.counters.tx_errors >= 3 and link.faults.bus_error
    assert "sends failed in a row (last: BrokenPipeError: [Errno 32] Broken pipe)" in " ".join(link.faults.reasons)
    link.close()


def test_link_config_validation():
    with pytest.raises(ValueError, match="control_rate_hz"):
        LinkConfig(control_rate_hz=500)
    with pytest.raises(ValueError, match="stale_after_s"):
        LinkConfig(stale_after_s=-1)
    with pytest.raises(ValueError, match="ecu_address"):
        LinkConfig(ecu_address=166)
    for bad in (0.0, 0.2, float("nan")):
        with pytest.raises(ValueError, match=r"check_period_s.*0\.001.*0\.05"):
            LinkConfig(check_period_s=bad)
    assert LinkConfig().control_period_s == pytest.approx(0.02) and LinkConfig().hitch_source == 169
    assert LinkConfig(hitch_status_address=240).hitch_source == 240


def test_link_and_ecu_node_in_real_time_on_a_virtual_bus(model):
    """Both nodes on background threads (RealtimeRunner): claim, measure, stream, stop, close.
    Only eventual behaviour is checked (no timing assertions)."""
    import time

    from bridge.link.realtime import RealtimeRunner, open_bus
    from bridge.sim.can_node import EcuCanNode
    from bridge.sim.ecu import CylinderECU

    ch = f"rt-{uuid.uuid4().hex}"
    ecu_bus, link_bus = open_bus("virtual", ch), open_bus("virtual", ch)
    node = EcuCanNode(CylinderECU(model.profile), ecu_bus)
    link = CanLink(model, link_bus, own_bus=True)
    runners = [RealtimeRunner(node).start(), RealtimeRunner(link).start()]
    try:
        deadline = time.monotonic() + 5.0
        while (link.latest_state() is None or not link.claimed) and time.monotonic() < deadline:
            time.sleep(0.02)  # the ECU may claim (and measure) before the link's own claim is done
        assert link.claimed and link.latest_state() is not None
        goal = ExactInverse(model)(0.0, 0.2, 0.0, 0.0)
        link.send_reference(goal, runners[1].now())
        while node.ecu.reference_counts() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert list(node.ecu.reference_counts()) == list(link.check_reference(goal).as_tuple())
        link.stop_motion()
    finally:
        for r in runners:
            r.stop()
        link.close()
        ecu_bus.shutdown()
    assert all(r.error is None for r in runners)
    assert link.counters.references_tx >= 1 and link.counters.malformed == 0
