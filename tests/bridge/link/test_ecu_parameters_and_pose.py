"""The planner's own messages the DBC declares and the link never sent (an integrator's finding): 0xFF23
EcuParameters — controllers on and the reference watchdog the link assumes, after its claim and whenever the
ECU starts or restarts — and 0xFF25 MeasuredPose every 100 ms while the measurements are fresh."""

from __future__ import annotations

import can
import pytest

from bridge.isobus.codec import EcuParameters, MeasuredPose, decode_frame
from bridge.isobus.j1939 import PGN_MEASURED_POSE, PGN_PARAMETERS, decode_id
from bridge.link.state import LinkConfig, LinkError
from bridge.sim.can_node import FaultSettings
from bridge.sim.move import SimRig


def _frames(tap: can.BusABC, pgn: int) -> list[can.Message]:
    out = []
    while (f := tap.recv(timeout=0.0)) is not None:
        ident = decode_id(f.arbitration_id)
        if ident.pgn == pgn and ident.source_address == 166:
            out.append(f)
    return out


def test_an_ecu_that_powers_up_with_controllers_off_and_another_watchdog_is_brought_to_what_the_link_assumes(model):
    with SimRig(model) as rig:
        rig.ecu.controllers_enabled = False
        rig.ecu.watchdog.timeout_s = 0.5
        tap = can.Bus(interface="virtual", channel=rig.channel)
        try:
            rig.start()
            rig.run_until(0.6)
            sent = [decode_frame(f).payload for f in _frames(tap, PGN_PARAMETERS)]
        finally:
            tap.shutdown()
        assert sent and all(p == EcuParameters(controllers_enabled=True, watchdog_timeout_s=0.1) for p in sent), sent
        assert rig.link.counters.parameters_tx == len(sent)
        assert rig.node.counters.parameters >= 1
        assert rig.ecu.controllers_enabled and rig.ecu.watchdog.timeout_s == pytest.approx(0.1)
        assert not rig.link.faults.any, rig.link.faults.reasons


def test_a_restarted_ecu_gets_the_parameters_again(rig):
    before = rig.link.counters.parameters_tx
    assert before >= 1 and rig.ecu.controllers_enabled
    rig.ecu.controllers_enabled = False  # as a real ECU's power-up defaults would be
    rig.ecu.watchdog.timeout_s = 0.5
    rig.node.apply_fault({"restart_ecu": True})
    rig.run_until(rig.now_s + 0.5)
    assert rig.link.faults.ecu_restart
    assert rig.link.counters.parameters_tx > before
    assert rig.ecu.controllers_enabled and rig.ecu.watchdog.timeout_s == pytest.approx(0.1)


def test_the_watchdog_the_link_assumes_must_be_one_0xff23_can_set():
    with pytest.raises(LinkError, match=r"ecu_watchdog_timeout_s must be a number of seconds in \[0.01, 2.5\]"):
        LinkConfig(ecu_watchdog_timeout_s=5.0)


def test_the_measured_pose_goes_every_100_ms_while_fresh_and_none_while_stale(rig):
    from bridge.link.can_link import MEASURED_POSE_PERIOD_S

    assert MEASURED_POSE_PERIOD_S == 0.1
    tap = can.Bus(interface="virtual", channel=rig.channel)
    try:
        t0 = rig.now_s
        rig.run_until(t0 + 1.0)
        poses = _frames(tap, PGN_MEASURED_POSE)
        assert 9 <= len(poses) <= 11, len(poses)
        assert rig.link.counters.poses_tx >= len(poses)
        got = decode_frame(poses[-1]).payload
        assert isinstance(got, MeasuredPose)
        p = rig.link.latest_state().pose
        assert got.x_m == pytest.approx(p.x, abs=2e-4) and got.z_m == pytest.approx(p.z, abs=2e-4)
        assert got.roll_rad == pytest.approx(p.roll, abs=2e-4) and got.pitch_rad == pytest.approx(p.pitch, abs=2e-4)
        # the measurements stop: none once they are stale
        rig.node.apply_fault(FaultSettings(cut="ecu_to_planner"))
        rig.run_until(rig.now_s + rig.link.config.stale_after_s + MEASURED_POSE_PERIOD_S)
        _frames(tap, PGN_MEASURED_POSE)
        rig.run_until(rig.now_s + 0.5)
        assert _frames(tap, PGN_MEASURED_POSE) == []
        assert rig.link.faults.stale_measurement
        # and again once they are fresh
        rig.node.apply_fault(FaultSettings())
        rig.run_until(rig.now_s + 0.5)
        assert len(_frames(tap, PGN_MEASURED_POSE)) >= 3
    finally:
        tap.shutdown()
