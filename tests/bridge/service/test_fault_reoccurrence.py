"""A latching fault that happens again after its acknowledgement is a new fault (a CAN fuzz trial).

``faults/ack`` cleared the service's copy of a latched fault but the link kept its flag latched until the
next accepted reference; the controller reports only faults the link did not hold at its last look, so a
second ECU restart after the ack showed ``faults: []`` (the link's ``link_faults: ['ecu_restart']``), wrote
no event, and the next goto was accepted. Now the ack clears the link's flags of the faults it
acknowledges (nothing starts), and every new occurrence is a ``fault`` event that refuses motion.

Truth: the simulated ECU restarted twice (its restart counter in the system-state byte), on the real CAN
path in simulated time.
"""

from __future__ import annotations

from tests.helpers import SimService


def test_a_fault_after_its_ack_is_reported_again_and_refuses_motion(model, tmp_path):
    s = SimService(model, tmp_path / "hitch.sqlite3", settle_s=0.5)
    try:

        def faults() -> set[str]:
            return {f.name for f in s.mc.faults}

        def fault_events() -> list[dict]:
            return [e for e in s.events if e.get("event") == "fault" and "ecu_restart" in e.get("new", [])]

        s.rig.ecu.restart()
        s.run(0.5)
        assert "ecu_restart" in faults() and len(fault_events()) == 1, s.events
        s.run(1.0)
        assert s.ok("faults/ack")["acknowledged"] == ["ecu_restart"]
        assert "ecu_restart" not in faults()
        s.run(0.5)
        s.rig.ecu.restart()  # again, before any motion command
        s.run(0.5)
        assert "ecu_restart" in faults(), [(e["event"], e.get("new")) for e in s.events]
        assert len(fault_events()) == 2
        ok, r = s.call("goto", {"goal": {"z": 0.1}})
        assert not ok and "ecu_restart" in r["message"], r
        s.run(1.0)
        s.ok("faults/ack")
        s.run(0.3)
        assert s.ok("goto", {"goal": {"z": 0.1}})["accepted"]
    finally:
        s.close()


def test_an_acknowledged_faults_reason_leaves_the_link_with_it(model, tmp_path):
    """A review: the ack cleared ecu_restart's flag in the link but kept its reason while another flag (the
    ECU restart's own stale measurement) stayed latched there: ``link.faults.reasons`` still said "ECU restart"."""
    from bridge.link.state import LinkFaults

    s = SimService(model, tmp_path / "hitch.sqlite3", settle_s=0.5)
    try:
        link = s.rig.link
        link._faults = LinkFaults(  # two latched in the link, as after an ECU restart
            ecu_restart=True,
            stale_measurement=True,
            reasons=("ECU restart counter 0 -> 1", "no valid cylinder positions for 0.300 s"),
            reason_names=("ecu_restart", "stale_measurement"),
        )
        left = link.clear_faults(s.rig.now_s, ["ecu_restart"])
        assert left.active() == ("stale_measurement",)
        assert left.reasons == ("no valid cylinder positions for 0.300 s",) and left.reason_names == (
            "stale_measurement",
        )
    finally:
        s.close()
