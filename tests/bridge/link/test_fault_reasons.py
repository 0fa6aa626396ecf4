"""What the link's fault reasons say (an integrator who wrote his own ECU from the docs): each new occurrence of
a latched heartbeat fault gives its own reason, and the stale-measurement fault says why the frames that did
arrive were not taken — which reading, which sender — instead of "check the CAN cable" for all of them.

The ECU here is a bare bus on the link's channel that a test writes frames into by hand."""

from __future__ import annotations

import re
import uuid

import can
import numpy as np
import pytest

from bridge.isobus.codec import Heartbeat, PositionMeasurement, RearHitchStatus, encode
from bridge.link.can_link import CanLink
from bridge.link.state import LinkConfig
from bridge.link.virtual import InProcessBus
from planner.model.sensors import SensorScaling

_TICK_S = 0.01
#: a constant system state: running, no reference yet (bit 3), restart counter 0
_SYSTEM = 0x08


class HandEcu:
    """A link on a private channel and a bus that sends the ECU's frames as a test says (simulated time)."""

    def __init__(self, model, config: LinkConfig | None = None) -> None:
        channel = f"reasons-{uuid.uuid4().hex}"
        self.link = CanLink(model, InProcessBus(channel=channel), config, own_bus=True)
        self.bus = InProcessBus(channel=channel)
        scaling = SensorScaling(model.profile)
        c = [int(v) for v in scaling.to_counts(model.neutral)]  # lift, tilt, top, left, right
        self.counts = c
        self.lift = (c[0] - scaling.counts_min[0]) / (scaling.counts_max[0] - scaling.counts_min[0])
        self.k = 0
        self.sequence = 251
        self.link.start(0.0)

    @property
    def now_s(self) -> float:
        return self.k * _TICK_S

    def measurement(self, *, tilt: int | None = None, top: int | None = None, source: int = 169) -> can.Message:
        c = self.counts
        f = encode(
            PositionMeasurement(
                c[1] if tilt is None else None if tilt >= 1022 else tilt,
                c[2] if top is None else None if top >= 1022 else top,
                c[4],
                c[3],
                _SYSTEM,
            ),
            source=source,
        )
        data = bytearray(f.data)  # a missing reading is 1023 (not available); 1022 (error) is its last bit cleared
        if tilt == 1022:
            data[1] &= ~0x40 & 0xFF
        if top == 1022:
            data[2] &= ~0x10 & 0xFF
        return can.Message(arbitration_id=f.arbitration_id, is_extended_id=True, data=bytes(data))

    def hitch(self, *, source: int = 169) -> can.Message:
        return encode(RearHitchStatus(position=self.lift), source=source)

    def run(self, duration_s: float, *, heartbeat: str = "normal", meas=None, hitch=None) -> None:
        """Advance ``duration_s``: each tick a measurement (``meas(self)``, default a good one) and a hitch status
        (``hitch(self)``), a heartbeat every 10 ticks (normal, "stop", "repeat", "error" or "jump")."""
        for _ in range(round(duration_s / _TICK_S)):
            self.k += 1
            for frame in ((meas or HandEcu.measurement)(self), (hitch or HandEcu.hitch)(self)):
                if frame is not None:
                    self.bus.send(frame)
            if self.k % 10 == 0 and heartbeat != "stop":
                if heartbeat == "jump":  # 10 on from the last one sent
                    self.sequence = (self.sequence + 9) % 251
                seq = {"repeat": (self.sequence - 1) % 251, "error": 254}.get(heartbeat, self.sequence)
                self.bus.send(encode(Heartbeat(seq), source=169))
                if heartbeat in ("normal", "jump"):
                    self.sequence = 0 if self.sequence == 251 else (self.sequence + 1) % 251
            self.link.poll(self.now_s)

    def close(self) -> None:
        self.link.close()
        self.bus.shutdown()


@pytest.fixture
def ecu(model):
    e = HandEcu(model)
    e.run(0.6)
    assert e.link.claimed and not e.link.faults.any, e.link.faults.reasons
    yield e
    e.close()


def test_each_later_heartbeat_fault_gives_its_own_reason_not_the_first_ones(ecu):
    """Integrator: after one heartbeat timeout had cleared by fresh data, the faults a repeated counter, 254 and
    a jump of 10 caused were each reported as "timeout: none for 0.300 s; last counter 158" (the link recorded a
    reason only while its flag was unset, and the flag stays latched until the next command)."""
    link = ecu.link
    ecu.run(0.5, heartbeat="stop")
    assert link.faults.ecu_heartbeat and "timeout" in link.faults.reason_of("ecu_heartbeat")
    seen = [link.faults.reason_of("ecu_heartbeat")]
    for kind, said in (("repeat", "sequence error"), ("error", "sender error"), ("jump", "sequence error")):
        ecu.run(1.2)  # the heartbeat operational again (8 in sequence): its cause is gone, its flag still latched
        assert "ecu_heartbeat" not in link.fault_causes(ecu.now_s) and link.faults.ecu_heartbeat
        ecu.run(0.1, heartbeat=kind)
        ecu.run(0.02)
        reason = link.faults.reason_of("ecu_heartbeat")
        assert said in reason and "timeout" not in reason, (kind, reason)
        assert reason not in seen, (kind, reason)
        assert link.status(ecu.now_s).faults.reason_of("ecu_heartbeat") == reason
        seen.append(reason)
    # one reason per fault: a fault that keeps coming back does not grow the list
    assert link.faults.reason_names.count("ecu_heartbeat") == 1


def test_a_cause_back_before_the_next_poll_names_itself_in_the_status(ecu):
    """The service reads the status between the link's polls: a heartbeat silent again names its timeout there,
    not the older reason of the still latched fault."""
    link = ecu.link
    ecu.run(0.1, heartbeat="error")
    assert "sender error" in link.faults.reason_of("ecu_heartbeat")
    ecu.run(1.5)
    assert "ecu_heartbeat" not in link.fault_causes(ecu.now_s)
    ecu.run(0.3, heartbeat="stop")  # the last heartbeat 0.3 s ago: not silent long enough yet at the last poll
    status = link.status(ecu.now_s + 0.09)
    assert "timeout" in status.faults.reason_of("ecu_heartbeat"), status.faults.reasons


def _bad_dlc(e: HandEcu) -> can.Message:
    f = e.measurement()
    return can.Message(arbitration_id=f.arbitration_id, is_extended_id=True, data=bytes(f.data)[:4])


def _empty(e: HandEcu) -> can.Message:
    f = e.measurement()
    return can.Message(arbitration_id=f.arbitration_id, is_extended_id=True, data=b"")


def _hitch_raw(raw: int):
    def make(e: HandEcu) -> can.Message:
        f = e.hitch()
        return can.Message(arbitration_id=f.arbitration_id, is_extended_id=True, data=bytes([raw]) + bytes(f.data)[1:])

    return make


@pytest.mark.parametrize(
    "meas, hitch, said",
    [
        (_bad_dlc, None, r"last 0xFF22 rejected: .*DLC 4.* \((2[0-9]|30) rejected\)"),
        (_empty, None, r"last 0xFF22 rejected: .*DLC 0"),
        (lambda e: e.measurement(tilt=1022), None, r"last 0xFF22 rejected: tilt reading 1022 = error indicator \("),
        (lambda e: e.measurement(top=1023), None, r"last 0xFF22 rejected: top reading 1023 = not available"),
        (lambda e: e.measurement(tilt=1000), None, r"tilt reading 1000 counts outside the calibrated span \[26, 917\]"),
        (lambda e: e.measurement(source=170), None, r"frames from address 170 ignored \(\d+\): the ECU is 169"),
        (None, _hitch_raw(254), r"last rear hitch status rejected: rear hitch position 254 = error indicator"),
        (None, _hitch_raw(251), r"last rear hitch status rejected: .*251.*reserved"),
        (
            None,
            lambda e: e.hitch(source=240),
            r"lift position \(rear hitch status\) from the cylinder ECU \(address 169\).*: rear hitch status arrives "
            r"from 240, the service takes it from 169: set \[can\] hitch_status_address",
        ),
    ],
    ids=["dlc4", "dlc0", "1022", "1023", "beyond-span", "sa170", "hitch-254", "hitch-251", "hitch-from-240"],
)
def test_the_stale_fault_says_why_the_frames_that_arrived_were_not_taken(ecu, meas, hitch, said):
    """Integrator: DLC 4 or 0, readings 1022/1023, a reading beyond the calibrated span, sender 170, a rear hitch
    status of 251/254 or from the TECU's 240 all gave "no valid … check the CAN cable and the ECU's power"."""
    ecu.run(0.3, meas=meas, hitch=hitch)
    reason = ecu.link.faults.reason_of("stale_measurement")
    assert reason is not None and "stale_measurement" in ecu.link.fault_causes(ecu.now_s)
    assert "check the CAN cable" not in reason, reason
    assert re.search(said, reason), reason


def test_nothing_at_all_still_says_check_the_cable(ecu):
    ecu.run(0.3, meas=lambda e: None)
    reason = ecu.link.faults.reason_of("stale_measurement")
    assert reason is not None and "check the CAN cable" in reason and "rejected" not in reason


def test_the_lift_from_the_tractors_address_names_it(model):
    """``hitch_status_address`` 240 (the thesis tractor's TECU): its frames are taken, and without them the fault
    names the address the link listens to and the one the frames come from."""
    e = HandEcu(model, LinkConfig(hitch_status_address=240))
    try:
        e.run(0.6, hitch=lambda e: e.hitch(source=240))
        assert not e.link.faults.any, e.link.faults.reasons
        e.run(0.3)  # the hitch status from 169 now
        reason = e.link.faults.reason_of("stale_measurement")
        assert "lift position (rear hitch status) from the tractor (address 240)" in reason, reason
        assert "arrives from 169, the service takes it from 240" in reason, reason
    finally:
        e.close()


def test_rejections_are_counted_from_the_last_frame_taken(ecu):
    ecu.run(0.3, meas=lambda e: e.measurement(tilt=1022))
    first = ecu.link.faults.reason_of("stale_measurement")
    ecu.run(0.3)  # good frames again
    assert "stale_measurement" not in ecu.link.fault_causes(ecu.now_s)
    assert np.isfinite(ecu.link.latest_state().counts[1])
    ecu.link.send_reference(ecu.link.model.neutral, ecu.now_s)  # re-arm: a fresh command clears the flags
    ecu.run(0.25, meas=lambda e: e.measurement(top=1023))
    reason = ecu.link.faults.reason_of("stale_measurement")
    assert reason != first and "top reading 1023" in reason and "tilt" not in reason
    n = int(reason.rsplit("(", 1)[1].split()[0])
    assert 20 <= n <= 25, reason  # this episode's frames only


def test_a_heartbeat_back_after_a_gap_says_the_gap_not_none_for_zero_seconds(ecu):
    """An operator trial: "ECU heartbeat timeout: none for 0.000 s (limit 0.3 s)": the timeout state latched from
    a late heartbeat (not yet 8 in sequence) was said with the age of the newest one. Now the gap is said."""
    link = ecu.link
    ecu.run(0.5, heartbeat="stop")
    ecu.run(0.15)  # heartbeats again, one or two: the monitor still in its timeout state
    hb = link.status(ecu.now_s).heartbeat
    assert hb.state.value == "timeout" and hb.age_s is not None and hb.age_s < 0.3 and hb.last_gap_s > 0.5, hb
    reason = link.status(ecu.now_s).faults.reason_of("ecu_heartbeat")
    assert f"a gap of {hb.last_gap_s:.3f} s between two (limit 0.3 s)" in reason and "none for" not in reason, reason
