"""The simulated cylinder ECU as a CAN node: start-up (claim, heartbeat, measurements) timing,
hand-checked frames, watchdog through the bus, parameters, malformed frames, address-claim
contention, restart, own echo. (The ECU as its own process: tests/integration/test_ecu_process.py,
on the loopback hub.)"""

import contextlib
import uuid

import can
import numpy as np
import pytest

from bridge.isobus.address_claim import ClaimState, cylinder_ecu_name
from bridge.isobus.codec import (
    AddressClaimed,
    EcuParameters,
    Heartbeat,
    PositionCounts,
    PositionMeasurement,
    RearHitchStatus,
    decode_frame,
    encode,
)
from bridge.isobus.j1939 import (
    PGN_HEARTBEAT,
    PGN_POSITION_MEASUREMENT,
    PGN_REAR_HITCH_STATUS,
    LimitStatus,
    decode_id,
)
from bridge.isobus.system_state import STATE_CONTROLLERS_ON, STATE_NO_REFERENCE, STATE_WATCHDOG_TRIPPED
from bridge.sim import CylinderECU
from bridge.sim.can_node import EcuCanNode, EcuNodeConfig, lift_fraction
from bridge.sim.move import SimRig
from planner.model.exact_inverse import ExactInverse

TICK = 0.001


@pytest.fixture
def channel():
    return f"test-{uuid.uuid4().hex}"


@pytest.fixture
def buses(channel):
    opened = []

    def make(**kw):
        b = can.Bus(interface="virtual", channel=channel, **kw)
        opened.append(b)
        return b

    yield make
    for b in opened:
        b.shutdown()


def drain(bus):
    out = []
    while (f := bus.recv(timeout=0.0)) is not None:
        out.append(f)
    return out


def run(nodes, t_from, t_to, listener=None):
    """Poll nodes every 1 ms on an integer grid; returns [(t, frame)] the listener saw."""
    seen = []
    for k in range(int(round(t_from / TICK)) + 1, int(round(t_to / TICK)) + 1):
        t = k * TICK
        for n in nodes:
            n.poll(t)
        if listener is not None:
            seen += [(t, f) for f in drain(listener)]
    return seen


def pack_msb_first(values_and_widths, total_bytes=8) -> bytes:
    """Independent packer: fields MSB first, the rest ones (the DBC comment's layout)."""
    acc, used = 0, 0
    for value, width in values_and_widths:
        acc, used = (acc << width) | value, used + width
    spare = 8 * total_bytes - used
    return ((acc << spare) | ((1 << spare) - 1)).to_bytes(total_bytes, "big")


def reference_frame(tilt, top, lift, right, left, source=166, dlc=8):
    data = pack_msb_first([(tilt, 10), (top, 10), (lift, 10), (right, 10), (left, 10)])[:dlc]
    return can.Message(arbitration_id=(3 << 26) | (0xFF21 << 8) | source, is_extended_id=True, data=data)


def test_start_up_claim_heartbeat_and_periodic_frames(buses):
    node = EcuCanNode(CylinderECU(), buses())
    listener = buses()
    node.start(0.0)
    first = drain(listener)
    assert len(first) == 1 and decode_id(first[0].arbitration_id).source_address == 169
    assert decode_frame(first[0]).payload == AddressClaimed(cylinder_ecu_name().value)
    seen = run([node], 0.0, 1.0, listener)
    assert min(t for t, _ in seen) == pytest.approx(0.25)  # nothing within the 250 ms claim window
    by_pgn = {}
    for t, f in seen:
        by_pgn.setdefault(decode_id(f.arbitration_id).pgn, []).append((t, decode_frame(f).payload))
    hb = by_pgn[PGN_HEARTBEAT]
    assert [p.sequence for _, p in hb] == [251, 0, 1, 2, 3, 4, 5, 6]
    assert np.allclose(np.diff([t for t, _ in hb]), 0.1)  # ISO 11783-7: 100 ms
    meas = by_pgn[PGN_POSITION_MEASUREMENT]
    assert len(meas) == 76 and np.allclose(np.diff([t for t, _ in meas]), 0.01)  # 100 Hz, 0.25 .. 1.00 s
    c = [int(v) for v in node.ecu.measurement_counts()]  # lift, tilt, top, left, right
    assert meas[-1][1] == PositionMeasurement(
        c[1], c[2], c[4], c[3], STATE_CONTROLLERS_ON | STATE_WATCHDOG_TRIPPED | STATE_NO_REFERENCE
    )
    hitch = by_pgn[PGN_REAR_HITCH_STATUS]
    assert len(hitch) == 76
    # neutral lift 0.220 rad: (0.220 + 0.223) / 0.886 * 229 + 26 = 140.5 -> AD 141 (half up);
    # fraction (141 - 26) / 229 = 0.50218 -> 126 steps of 0.4 % = 0.504
    assert c[0] == 141
    assert hitch[-1][1].position == pytest.approx(0.504)


def test_hitch_status_frame_hand_checked(buses):
    node = EcuCanNode(CylinderECU(), buses())
    listener = buses()
    node.start(0.0)
    seen = run([node], 0.0, 0.26, listener)
    frame = next(f for _, f in seen if decode_id(f.arbitration_id).pgn == PGN_REAR_HITCH_STATUS)
    assert frame.arbitration_id == 0x0CFE45A9  # priority 3, PGN 0xFE45, source 169
    assert frame.data[0] == 126  # 0.504 / 0.004
    assert frame.data[1] >> 3 & 0x7 == 0  # limit status: not limited


def test_lift_fraction_hand_values():
    assert lift_fraction(26, 26, 255) == 0.0
    assert lift_fraction(255, 26, 255) == 1.0
    assert lift_fraction(140.5, 26, 255) == pytest.approx(114.5 / 229)
    assert lift_fraction(10, 26, 255) == 0.0 and lift_fraction(300, 26, 255) == 1.0  # clipped, never reserved


def test_every_lift_count_survives_the_hitch_status_byte():
    """Sender count → 0.4 %/bit byte (encoded and decoded by the codec) → link: the same count.

    The fraction alone is off by up to half a 0.4 % step (0.46 count); on the count grid the
    round trip is exact for all 230 readings of the thesis's lift (26..255, table 3-2)."""
    from bridge.link.state import lift_counts_from_fraction

    worst_linear = 0.0
    for c in range(26, 256):
        frame = encode(RearHitchStatus(position=lift_fraction(c, 26, 255)), source=169)
        frac = decode_frame(frame).payload.position
        assert lift_counts_from_fraction(frac, 26, 255) == c
        worst_linear = max(worst_linear, abs(lift_counts_from_fraction(frac, 26, 255, on_count_grid=False) - c))
    assert 0.4 < worst_linear <= 0.5 * 229 / 250 + 1e-9
    # on by default only when our own ECU sends the hitch status (its mapping is known)
    from bridge.link.state import LinkConfig

    assert LinkConfig().lift_count_grid and not LinkConfig(hitch_status_address=240).lift_count_grid
    assert LinkConfig(hitch_status_address=169).lift_count_grid  # the cylinder ECU named explicitly: its mapping
    assert LinkConfig(hitch_status_address=240, lift_on_count_grid=True).lift_count_grid
    with pytest.raises(ValueError, match="lift_on_count_grid"):
        LinkConfig(lift_on_count_grid="yes")
    # a span longer than the 250 steps cannot be recovered: linear value, not a wrong count
    assert lift_counts_from_fraction(0.5, 0, 600) == 300.0
    assert lift_counts_from_fraction(0.5004, 0, 600) == pytest.approx(300.24)


def low_and_high(model):
    """Actuators at z = -0.2 m and z = +0.3 m: a lift move of seconds at full valve opening."""
    inv = ExactInverse(model)
    return inv(0.0, -0.2, 0.0, 0.0), inv(0.0, 0.3, 0.0, 0.0)


@contextlib.contextmanager
def _moving(model):
    """A rig whose planner has streamed a reference from ``low`` to ``high`` for 0.5 s (the ECU drives): (rig,
    the high reference)."""
    low, high = low_and_high(model)
    with SimRig(model, initial_actuators=low) as rig:
        rig.start()
        rig.run_until(0.5)
        rig.link.send_reference(high, rig.next_tick_s)
        rig.run_until(1.0)
        yield rig, high


def test_watchdog_stops_the_valves_within_100_ms_of_the_last_reference(model):
    low, high = low_and_high(model)
    with SimRig(model, initial_actuators=low) as rig:
        tap = can.Bus(interface="virtual", channel=rig.channel)
        rig.start()
        rig.run_until(0.5)
        rig.link.send_reference(high, rig.next_tick_s)
        rig.run_until(1.5)
        assert rig.ecu.valve_commands()[0] != 0
        rig.link.stop_motion()
        t_stop = rig.now_s
        log = []
        while rig.now_s < t_stop + 0.3:
            t = rig.tick()
            log.append((t, rig.ecu.valve_commands().copy()))
        refs = [f for f in drain(tap) if decode_id(f.arbitration_id).pgn == 0xFF21]
        tap.shutdown()
    last = rig.ecu.watchdog.last_feed_s
    assert last == pytest.approx(t_stop, abs=0.0201)  # the last reference of the 50 Hz stream
    assert refs  # the stream really was on the bus
    before = [v for t, v in log if t < last + 0.1 - 1e-9]
    after = [v for t, v in log if t >= last + 0.1 - 1e-9]
    assert before and before[-1][0] != 0  # still driving 1 ms before the timeout
    assert after and all(not v.any() for v in after)  # zero from 100 ms after the last reference on
    assert rig.ecu.watchdog.trip_count == 1


def test_parameters_switch_controllers_and_watchdog_and_refuse_multipliers(model):
    with _moving(model) as (rig, high):
        applied = rig.node.counters.parameters  # the link's own 0xFF23 after its claim (controllers on, watchdog)
        rig.link.send_parameters(EcuParameters(valve_multipliers=(0.5, None, None, None, None)), rig.now_s)
        rig.run_until(1.02)
        assert rig.node.counters.parameters_rejected == 1 and rig.node.counters.parameters == applied
        assert rig.ecu.controllers_enabled and rig.ecu.valve_commands()[0] != 0
        rig.link.send_parameters(EcuParameters(controllers_enabled=False), rig.now_s)
        rig.tick()
        assert not rig.ecu.valve_commands().any()
        rig.run_until(1.1)
        assert not rig.link.latest_state().system.controllers_on  # seen back through 0xFF22
        rig.link.send_parameters(EcuParameters(controllers_enabled=True, watchdog_timeout_s=0.05), rig.now_s)
        rig.run_until(1.5)
        assert rig.ecu.watchdog.timeout_s == pytest.approx(0.05) and rig.ecu.valve_commands()[0] != 0
        rig.link.stop_motion()
        last = rig.ecu.watchdog.last_feed_s
        rig.run_until(last + 0.049)
        assert rig.ecu.valve_commands()[0] != 0
        rig.run_until(last + 0.05)
        assert not rig.ecu.valve_commands().any()


def test_malformed_and_foreign_frames_never_reach_the_ecu(buses):
    node = EcuCanNode(CylinderECU(), buses())
    planner = buses()
    node.start(0.0)
    run([node], 0.0, 0.3)
    bad = [
        reference_frame(400, 100, 1022, 200, 200),  # lift = error indicator
        reference_frame(400, 100, 1023, 200, 200),  # lift = not available
        reference_frame(400, 100, 140, 200, 200, dlc=7),  # wrong DLC
    ]
    for f in bad:
        planner.send(f)
    planner.send(reference_frame(400, 100, 140, 200, 200, source=0x80))  # not the planner
    planner.send(can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x00" * 8))
    planner.send(
        can.Message(arbitration_id=(6 << 26) | (0xFE49 << 8) | 0x80, is_extended_id=True, data=b"\xff" * 8)
    )  # an ISOBUS PGN the DBC does not describe
    planner.send(can.Message(is_error_frame=True))
    run([node], 0.3, 0.31)
    c = node.counters
    assert (c.malformed, c.references, c.unknown_pgn, c.error_frames) == (3, 0, 1, 1)
    assert c.ignored == 2
    assert node.ecu.reference_counts() is None
    assert "1022" in node.last_malformed or "DLC" in node.last_malformed
    planner.send(reference_frame(400, 100, 140, 200, 200))  # valid, hand-packed
    run([node], 0.31, 0.32)
    assert node.counters.references == 1
    assert list(node.ecu.reference_counts()) == [140, 400, 100, 200, 200]  # lift, tilt, top, left, right


def test_address_claim_contention_lower_name_wins(buses):
    loser = EcuCanNode(CylinderECU(), buses(), EcuNodeConfig(name=cylinder_ecu_name(identity_number=7)))
    winner = EcuCanNode(CylinderECU(), buses(), EcuNodeConfig(name=cylinder_ecu_name(identity_number=3)))
    planner, listener = buses(), buses()
    loser.start(0.0)
    winner.start(0.0)
    seen = run([loser, winner], 0.0, 0.6, listener)
    assert loser.claim_state is ClaimState.CANNOT_CLAIM and winner.claim_state is ClaimState.CLAIMED
    cannot = [f for _, f in seen if decode_id(f.arbitration_id).source_address == 254]
    assert len(cannot) == 1 and decode_frame(cannot[0]).payload.name == cylinder_ecu_name(7).value
    assert loser.counters.frames_tx == 2  # its claim and its cannot-claim, then silence
    planner.send(encode(PositionCounts(140, 400, 100, 200, 200)))
    run([loser, winner], 0.6, 0.61)
    assert loser.ecu.reference_counts() is None
    assert winner.ecu.reference_counts() is not None


def test_restart_reclaims_then_heartbeat_251_and_restart_bits(buses):
    node = EcuCanNode(CylinderECU(), buses())
    listener = buses()
    node.start(0.0)
    run([node], 0.0, 0.5)
    drain(listener)
    node.restart(0.5)
    seen = run([node], 0.5, 1.0, listener)
    assert min(t for t, _ in seen) == pytest.approx(0.501)  # the claim goes out at the first poll
    hb = [(t, decode_frame(f).payload) for t, f in seen if decode_id(f.arbitration_id).pgn == PGN_HEARTBEAT]
    assert decode_frame(seen[0][1]).payload == AddressClaimed(cylinder_ecu_name().value)
    assert hb[0] == (pytest.approx(0.75), Heartbeat(251))  # silent for the 250 ms claim window
    meas = [decode_frame(f).payload for t, f in seen if decode_id(f.arbitration_id).pgn == PGN_POSITION_MEASUREMENT]
    assert meas[0].system_state >> 4 == 1 and meas[0].system_state & STATE_NO_REFERENCE
    assert node.counters.restarts == 1


def test_own_echo_is_ignored(buses):
    node = EcuCanNode(CylinderECU(), buses(receive_own_messages=True))
    node.start(0.0)
    run([node], 0.0, 0.5)
    assert node.claim_state is ClaimState.CLAIMED
    c = node.counters
    assert c.frames_rx > 0 and c.malformed == 0 and c.references == 0 and c.ignored == 0


def test_the_twins_periodic_frames_share_one_grid_so_its_runner_wakes_once_per_period(buses):
    """The ECU anchors its 100 Hz measurement and hitch status on the grid k · 10 ms of node time,
    the tractor twin sends on the same grid from its start: driven as the runner drives them (wake
    at the earliest deadline, poll, repeat) the twin wakes once per 10 ms period plus its heartbeat,
    and the ECU's measurements leave at the same instants as the slope sensor's frames. (Before, the
    ECU anchored at its claim time, off the tractor's grid: two wake-ups per period on both sides.)
    The driver wakes 0.1–0.9 ms after each deadline, as a real runner does."""
    from bridge.isobus.messages import PGN_SLOPE_SENSOR_INFORMATION
    from bridge.link.realtime import SharedBusNodes
    from bridge.sim.tractor_node import TractorTwinNode

    twin = SharedBusNodes(buses())
    listener = buses()
    ecu_node = EcuCanNode(CylinderECU(), twin.port())
    twin.add(ecu_node).add(TractorTwinNode(twin.port(), ground_speed_m_s=1.5))
    twin.start(0.0)
    rng = np.random.default_rng(4)
    t, wakes, sent_at = 0.0, [], {PGN_POSITION_MEASUREMENT: set(), PGN_SLOPE_SENSOR_INFORMATION: set()}
    while t < 3.0:
        twin.poll(t)
        for f in drain(listener):
            pgn = decode_id(f.arbitration_id).pgn
            if pgn in sent_at:
                sent_at[pgn].add(round(t, 6))
        if t >= 1.0:
            wakes.append(t)
        t = max(twin.next_due_s(), t) + float(rng.uniform(1e-4, 9e-4))  # a runner wakes a little late
    assert ecu_node.claim_state is ClaimState.CLAIMED
    per_s = len(wakes) / 2.0
    assert per_s <= 100 + 10 + 2, f"{per_s:.1f} wake-ups per second"
    measured = {x for x in sent_at[PGN_POSITION_MEASUREMENT] if x >= 1.0}
    slope = {x for x in sent_at[PGN_SLOPE_SENSOR_INFORMATION] if x >= 1.0}
    assert len(measured) >= 195 and measured <= slope


def test_each_periodic_frame_carries_the_ecus_state_of_its_send_time(buses):
    """The node builds a frame only when what it is made of changed (a hitch at rest sends the same two
    frames 100 times a second): every 0xFF22 and rear hitch status on the bus must still be the one a fresh
    encoding of the ECU's state at that moment gives, through moves, a controller switch and a watchdog trip."""
    node = EcuCanNode(CylinderECU(), buses())
    listener = buses()
    node.start(0.0)
    run([node], 0.0, 0.3)
    drain(listener)
    ecu = node.ecu
    start = [int(v) for v in ecu.measurement_counts()]
    goal = [c + d for c, d in zip(start, (40, -30, 25, 20, -20), strict=True)]  # lift, tilt, top, left, right
    checked, distinct = 0, set()
    for k in range(31, 301):  # 0.31 .. 3.00 s, one poll per 10 ms
        t = k * 0.01
        if k < 150 and k % 5 == 0:
            ecu.set_reference(goal, t - 0.005)  # driving (the watchdog trips after 100 ms without a reference)
        if k == 200:
            ecu.controllers_enabled = False
        if k == 250:
            ecu.controllers_enabled = True
        node.poll(t)
        frames = {decode_id(f.arbitration_id).pgn: f for f in drain(listener)}
        c, state = ecu.measurement_tuple(), ecu.system_state()
        fresh = encode(PositionMeasurement(c[1], c[2], c[4], c[3], state), source=169)
        lift_min, lift_max = ecu.lift_calibration_counts()
        fraction = lift_fraction(c[0], lift_min, lift_max)
        limit = LimitStatus.NOT_LIMITED
        if ecu.relay_engaged()[0]:
            limit = LimitStatus.LIMITED_HIGH if fraction > 0.5 else LimitStatus.LIMITED_LOW
        hitch = encode(RearHitchStatus(position=fraction, limit_status=limit), source=169)
        assert bytes(frames[PGN_POSITION_MEASUREMENT].data) == bytes(fresh.data), t
        assert frames[PGN_POSITION_MEASUREMENT].arbitration_id == fresh.arbitration_id
        assert bytes(frames[PGN_REAR_HITCH_STATUS].data) == bytes(hitch.data), t
        checked += 1
        distinct.add((c, state))
    assert checked == 270 and len(distinct) > 20  # the counts and the state byte did change meanwhile


def test_a_link_started_after_the_ecu_learns_its_name(buses, model):
    """The ECU is powered first (on a tractor it always is) and claimed its address before the planner's link
    started. Before, the link learned the ECU's NAME only from a claim it happened to hear, so a resumed sensor
    calibration recorded "an unnamed machine" and could resume another machine's end readings (a commissioning
    trial). The link now asks everyone for their claims when it starts (a global Request for PGN 60928)."""
    from bridge.link.can_link import CanLink

    node = EcuCanNode(CylinderECU(), buses())
    node.start(0.0)
    run([node], 0.0, 1.0)  # claimed, heartbeating
    link = CanLink(model, buses())
    link.start(1.0)
    for k in range(1, 301):
        t = 1.0 + k * TICK
        node.poll(t)
        link.poll(t)
    assert link.peer_name(169) == cylinder_ecu_name()


@pytest.mark.parametrize("stalled", ["ecu", "hub"])
def test_references_queued_during_a_stall_longer_than_the_watchdog_never_move_a_cylinder(model, stalled):
    """Safety tester: during a goto the CAN hub (or the ECU process) was stopped for 3 s; after it
    went on, the references queued meanwhile arrived in a burst, fed the ECU's watchdog when read, and
    the ECU drove about 100 ms on references seconds old while the planner had long stopped."""
    with _moving(model) as (rig, high):
        assert rig.ecu.valve_commands()[0] != 0  # moving
        held = []
        t_stall = rig.now_s
        if stalled == "ecu":  # kill -STOP ecu-sim: neither reads nor sends; the planner's frames wait in its queue
            rig.ecu_paused = True
        else:  # kill -STOP the hub: the ECU runs on; frames each way wait in the hub
            rig.node.handle = lambda frame, now_s: held.append(frame)
            rig.node.bus.send = lambda frame, timeout=None: None
        rig.run_until(t_stall + 3.0)
        assert rig.link.faults.any and not rig.link.streaming  # the planner stopped long ago
        rig.ecu.step(rig.now_s)  # the machine: the watchdog closed the valves 100 ms into the stall
        before = rig.ecu.piston_counts().copy()
        assert not rig.ecu.valve_commands().any()
        if stalled == "ecu":
            rig.ecu_paused = False  # kill -CONT: the queued frames are read at once
        else:
            del rig.node.handle, rig.node.bus.send
            refs = [f for f in held if decode_id(f.arbitration_id).pgn == 0xFF21]
            assert len(refs) >= 5
            for frame in held:  # the hub delivers its backlog in a burst
                rig.node.handle(frame, rig.next_tick_s)
        valves = []
        while rig.now_s < t_stall + 4.0:
            rig.tick()
            valves.append(rig.ecu.valve_commands().copy())
        assert rig.node.counters.references > 0
        assert not np.any(valves), "the ECU acted on references queued during the stall"
        assert np.max(np.abs(rig.ecu.piston_counts() - before)) < 1e-6


def test_after_a_trip_a_live_stream_re_arms_the_ecu_within_about_60_ms(model):
    """The re-arm costs a live planner one re-arm window: a new command after a fault moves at once after it."""
    with _moving(model) as (rig, high):
        rig.link.stop_motion()
        rig.run_until(1.5)
        assert rig.ecu.watchdog.trip_count == 1 and not rig.ecu.valve_commands().any()
        t0 = rig.next_tick_s
        rig.link.send_reference(high, t0)
        moved = None
        while rig.now_s < t0 + 0.2 and moved is None:
            t = rig.tick()
            if rig.ecu.valve_commands()[0] != 0:
                moved = t
        assert moved is not None and 0.05 <= moved - t0 <= 0.08
        rig.run_until(t0 + 0.5)
        assert not rig.link.faults.any and rig.link.streaming
