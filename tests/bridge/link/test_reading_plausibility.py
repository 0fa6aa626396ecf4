"""A reading that moves faster than its cylinder can is not taken (bridge.link.state, ``reading_rate_factor``).

A CAN fuzz trial: a node sending 0xFF22 as the ECU (address 169) with in-span, kinematically valid readings of
another pose, 300 times a second, interleaved with the ECU's own: the link took them, the next goto planned
from the spoofed pose and its first reference dropped the real lift by 31 counts. Now a reading that moved
since the last one taken by more than ``reading_rate_factor`` × its cylinder's full-valve speed
(``max(kv_pos, kv_neg) · 254`` counts/s) over the time between, plus the reading tolerance, is rejected,
naming the actuator; readings that keep to a new level among themselves for ``REANCHOR_S`` are taken then.

Truth: the allowance by hand from the profile's valve gains (thesis tables 3-3, 3-4); the simulated ECU's
own readings on the real CAN path.
"""

from __future__ import annotations

import can
import numpy as np
import pytest

from bridge.isobus.codec import PositionMeasurement, RearHitchStatus, encode
from bridge.link.state import REANCHOR_S, LinkConfig, LinkError, MeasurementAssembler
from planner.model.sensors import SensorScaling


def _assembler(model, **cfg):
    bumps: dict[str, int] = {}
    rx = MeasurementAssembler(
        model,
        SensorScaling(model.profile),
        LinkConfig(**cfg),
        lambda **d: [bumps.__setitem__(k, bumps.get(k, 0) + v) for k, v in d.items()],
    )
    return rx, bumps


def _neutral(model) -> list[int]:
    return [int(round(c)) for c in SensorScaling(model.profile).to_counts(model.neutral)]


def _send(rx, counts, t: float) -> None:
    _, tilt, top, left, right = counts
    rx.on_measurement(PositionMeasurement(tilt, top, right, left, system_state=1), t)


def test_the_allowance_is_the_full_valve_speed_times_the_factor_plus_the_tolerance(model):
    tilt = model.profile.actuator("tilt")
    full = max(tilt.kv_pos, tilt.kv_neg) * 254  # counts/s at full valve: 0.452 · 254 = 114.8
    dt = 0.01
    allowed = 3.0 * full * dt + 8.0  # reading_rate_factor 3, reading_jump_counts 8: 11.44 counts in 10 ms
    assert allowed == pytest.approx(11.44, abs=0.01)
    c = _neutral(model)
    for step, taken in ((int(np.floor(allowed)), True), (int(np.floor(allowed)) + 1, False)):
        rx, _ = _assembler(model)
        _send(rx, c, 0.0)
        moved = list(c)
        moved[1] += step
        _send(rx, moved, dt)
        assert (rx.last_problem == "") is taken, (step, rx.last_problem)
    assert "tilt reading jumped +12 counts in 10 ms" in rx.last_problem
    assert "a second node sending as address 169" in rx.last_problem


@pytest.mark.parametrize("spoof_first", [False, True])
def test_a_spoofed_pose_interleaved_with_the_ecus_frames_is_never_taken_and_stops_the_measurement(model, spoof_first):
    """Two levels from one address, whichever came first (a review: a spoof read before the ECU's first frame
    was trusted for good, the real readings rejected as jumps): after CONFLICT_COUNT far jumps none is taken,
    so the state ages and the stale fault stops motion, naming two senders."""
    rx, bumps = _assembler(model)
    real = _neutral(model)
    spoof = list(real)
    spoof[1] -= 40  # another pose, in span
    hitch = RearHitchStatus(position=0.5)
    for k in range(300):  # 1 s: the ECU at 100 Hz, the spoof at 300 Hz between its frames
        t = k / 300
        if (k % 3 == 0) != spoof_first:
            _send(rx, real, t)
            rx.on_hitch_status(hitch, t)
        else:
            _send(rx, spoof, t)
        if rx.state is not None:
            assert rx.state.counts[1] in (float(real[1]), float(spoof[1]))
            assert rx.state.measurement_t_s <= 0.05, (k, rx.state)  # nothing taken after the first few frames
    assert "two nodes sending as address 169?" in rx.last_problem, rx.last_problem  # the rate or the levels
    assert bumps["rejected_readings"] >= 290


def test_a_reading_that_keeps_to_a_new_level_is_taken_after_reanchor_s(model):
    rx, _ = _assembler(model)
    c = _neutral(model)
    _send(rx, c, 0.0)
    rx.on_hitch_status(RearHitchStatus(position=0.5), 0.0)
    top = model.profile.actuator("top")
    # a jump beyond what the top link could move even in REANCHOR_S: 3 · 0.257 · 254 · 0.3 + 8 = 66.8 counts
    assert 100 > 3.0 * max(top.kv_pos, top.kv_neg) * 254 * REANCHOR_S + 8.0
    new = list(c)
    new[2] += 100  # the top link's sensor replaced mid-run: a new level, steady
    t, k = 0.01, 1
    while t < 0.01 + REANCHOR_S - 0.005:
        _send(rx, new, t)
        assert rx.state is not None and rx.state.counts[2] == float(c[2]), (t, rx.state.counts)
        assert "top reading jumped +100 counts" in rx.last_problem, (t, rx.last_problem)
        k += 1
        t = 0.01 * k
    _send(rx, new, 0.01 + REANCHOR_S)
    assert rx.state is not None and rx.state.counts[2] == float(new[2])


def test_the_factor_is_checked_and_zero_turns_the_check_off(model):
    with pytest.raises(LinkError, match=r"reading_rate_factor must be 0 \(off\) or a number in \[1, 100\]"):
        LinkConfig(reading_rate_factor=0.5)
    with pytest.raises(LinkError, match=r"reading_jump_counts must be a number in \[0, 100\] counts"):
        LinkConfig(reading_jump_counts=-1.0)
    rx, _ = _assembler(model, reading_rate_factor=0.0)
    c = _neutral(model)
    _send(rx, c, 0.0)
    c[1] += 40
    _send(rx, c, 0.0)
    assert rx.last_problem == ""


def test_on_the_bus_a_spoofed_ecu_stops_motion_naming_two_senders_and_never_moves_the_measured_pose(rig, model):
    """The real CAN path: a rogue node sends another pose as the ECU after each of the ECU's frames; once it
    stops, the fault clears itself with fresh data."""
    link, ecu = rig.link, rig.ecu
    rogue = can.Bus(interface="virtual", channel=rig.channel)
    real = [int(v) for v in ecu.measurement_counts()]
    spoof = PositionMeasurement(real[1] - 40, real[2], real[4], real[3], ecu.system_state())
    try:
        for _ in range(100):  # 1 s
            rig.run_until(rig.now_s + 0.01)
            rogue.send(encode(spoof, source=169))
            link.poll(rig.now_s)
            state = link.latest_state()
            assert state is not None and state.counts[1] == float(real[1]), state.counts
        assert link.faults.stale_measurement, link.faults
        assert any("two nodes sending as address 169?" in r for r in link.faults.reasons), link.faults.reasons
    finally:
        rogue.shutdown()
    rig.run_until(rig.now_s + 2.5)  # the rogue gone: its frames leave the 1 s rate window, fresh readings again
    assert not link.fault_causes(rig.now_s)


def test_a_new_level_waits_for_the_stale_limit_when_that_is_longer_than_the_reanchor_time(model):
    """A review: with ``[can] stale_timeout_s = 1`` a wrong level was taken after 0.3 s, before any fault."""
    rx, _ = _assembler(model, stale_after_s=1.0)
    c = _neutral(model)
    _send(rx, c, 0.0)
    rx.on_hitch_status(RearHitchStatus(position=0.5), 0.0)
    new = list(c)
    top = model.profile.actuator("top")
    jump = 140  # far beyond 2 × what the top link could move in 10 ms, reached by the allowance only after
    t_allowed = (jump - 8.0) / (3.0 * max(top.kv_pos, top.kv_neg) * 254)  # 0.67 s: taken then, as a cylinder
    assert 0.3 < t_allowed < 1.0  # could have moved so far: after the old 0.3 s re-anchor, before the stale limit
    new[2] += jump
    k = 1
    while 0.01 * k < t_allowed - 0.01:
        _send(rx, new, 0.01 * k)
        assert rx.state is not None and rx.state.counts[2] == float(c[2]), (0.01 * k, rx.state.counts)
        k += 1


def test_a_forward_step_of_the_bus_clock_does_not_open_the_allowance(model):
    """A review: frames stamped 30 s later (a wall clock set at boot) let any jump through."""
    rx, _ = _assembler(model, bus_timestamps=True)
    c = _neutral(model)
    rx.on_measurement(PositionMeasurement(c[1], c[2], c[4], c[3], system_state=1), 0.0, stamp_s=1000.0)
    rx.on_hitch_status(RearHitchStatus(position=0.5), 0.0, stamp_s=1000.0)
    rx.on_measurement(PositionMeasurement(c[1] + 100, c[2], c[4], c[3], system_state=1), 0.01, stamp_s=1030.01)
    assert "tilt reading jumped +100 counts in 10 ms" in rx.last_problem, rx.last_problem


def test_two_levels_alternating_at_the_ecus_own_rate_are_refused_as_two_levels(model):
    """Frames at the ECU's rate (100 Hz in all) alternating between two levels 40 counts apart: the rate is
    normal, the levels are not."""
    rx, _ = _assembler(model)
    real = _neutral(model)
    spoof = list(real)
    spoof[1] -= 40
    for k in range(100):
        _send(rx, spoof if k % 2 else real, k * 0.01)
        rx.on_hitch_status(RearHitchStatus(position=0.5), k * 0.01)
    assert "0xFF22 readings alternate between two levels (tilt" in rx.last_problem, rx.last_problem


def test_a_spoof_within_the_jump_allowance_is_refused_by_the_rate_it_comes_at(model):
    """A recheck: a spoof 8 counts off (within the jump allowance) from address 169 at 300 frames/s alternated
    with the ECU's frames and was taken as the pose. Frames arriving at 3 times the ECU's rate are refused, on
    bus stamps (as the service reads them) within 0.15 s."""
    rx, _ = _assembler(model, bus_timestamps=True)
    real = _neutral(model)
    spoof = list(real)
    spoof[2] += 8
    hitch = RearHitchStatus(position=0.5)
    for k in range(300):  # 1 s
        t = k / 300
        if k % 3 == 0:
            rx.on_measurement(PositionMeasurement(real[1], real[2], real[4], real[3], 1), t, stamp_s=t)
            rx.on_hitch_status(hitch, t, stamp_s=t)
        else:
            rx.on_measurement(PositionMeasurement(spoof[1], spoof[2], spoof[4], spoof[3], 1), t, stamp_s=t)
    assert rx.state is not None and rx.state.measurement_t_s < 0.15, rx.state  # nothing taken since
    assert "0xFF22 arrives" in rx.last_problem and "the 100 a second its sender sends" in rx.last_problem, (
        rx.last_problem
    )


def test_a_stalls_backlog_read_at_once_is_not_taken_for_a_second_sender(model):
    """Frames at 100 Hz, 0.4 s of them held back by a stall and read at one time (no bus stamps)."""
    rx, _ = _assembler(model)
    c = _neutral(model)
    t_read = 0.0
    for k in range(200):
        t = k * 0.01
        t_read = t if not 0.5 <= t < 0.9 else t_read  # the stall: frames wait, read together at 0.9
        if 0.5 <= t < 0.9:
            continue
        if abs(t - 0.9) < 1e-9:
            for _ in range(40):  # the backlog
                _send(rx, c, 0.9)
        _send(rx, c, t)
        rx.on_hitch_status(RearHitchStatus(position=0.5), t)
        assert rx.last_problem == "", (t, rx.last_problem)


@pytest.mark.parametrize("stall_s", [0.85, 1.5, 5.0])
def test_a_longer_stalls_backlog_is_not_taken_for_a_second_sender_either(model, stall_s):
    """A review: stalls of 0.85–1.5 s (no bus stamps, the backlog read at once) had the ECU's readings refused
    as "two nodes sending as address 169" for 2 s after the backlog was read."""
    rx, _ = _assembler(model)
    c = _neutral(model)
    for k in range(int((3.0 + stall_s) / 0.01)):
        sent = k * 0.01
        now = 1.0 + stall_s if 1.0 <= sent < 1.0 + stall_s else sent
        _send(rx, c, now)
        rx.on_hitch_status(RearHitchStatus(position=0.5), now)
        assert "arrives" not in rx.last_problem, (sent, rx.last_problem)


def test_a_step_back_of_the_bus_clock_refuses_none_of_the_ecus_readings(model):
    """A review: the service stamps frames with the wall clock; a 5 s step back (NTP, a GNSS time fix) refused
    522 genuine readings as "two nodes" for 5.2 s (a stale fault) and grew the arrival list with every frame."""
    rx, bumps = _assembler(model, bus_timestamps=True)
    _, tilt, top, left, right = _neutral(model)
    for k in range(700):
        now = k * 0.01
        stamp = 1000.0 + now - (5.0 if now >= 1.0 else 0.0)
        rx.on_measurement(PositionMeasurement(tilt, top, right, left, system_state=1), now, stamp_s=stamp)
        rx.on_hitch_status(RearHitchStatus(position=0.5), now, stamp_s=stamp)
        assert rx.state is not None and rx.state.measurement_t_s == now, (now, rx.last_problem)
    assert bumps.get("rejected_readings", 0) == 0
