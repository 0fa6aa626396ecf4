"""The fault policy on its own (``bridge.service.motion.fault_book``), against the written rule of
``docs/faults.md``: a new link fault is raised once with its own reason; a self-clearing one is released only
after its cause has been absent for ``FAULT_CLEAR_AFTER_S`` without a break, and raised again when its cause
returns while the link still latches it; a latching one stays until acknowledged, and an acknowledge keeps
those whose cause the link still sees. Truth: the rule's own times and the order the test made things happen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from bridge.link.state import LinkFaults
from bridge.service.motion.fault_book import FaultBook, link_reason
from bridge.service.motion.types import FAULT_CLEAR_AFTER_S, Fault

STALE_S = 0.2


@dataclass(frozen=True)
class _Measured:
    t_s: float

    def age_s(self, now: float) -> float:
        return now - self.t_s


@dataclass(frozen=True)
class _Heartbeat:
    healthy: bool = True


@dataclass(frozen=True)
class _Status:
    """The parts of a ``LinkStatus`` the book reads (the faults are the link's real record)."""

    faults: LinkFaults
    state: _Measured | None
    heartbeat: _Heartbeat = _Heartbeat()
    fault_causes: tuple[str, ...] = ()
    address_problem: str = ""


def _latched(**reasons: str) -> LinkFaults:
    """The link's record with these faults latched, each with its reason (name=reason)."""
    return LinkFaults(**dict.fromkeys(reasons, True), reasons=tuple(reasons.values()), reason_names=tuple(reasons))


def _stale() -> LinkFaults:
    return _latched(stale_measurement="no valid cylinder positions for 0.3 s")


def test_a_new_link_fault_is_raised_once_with_its_own_reason():
    book = FaultBook(STALE_S)
    faults = _latched(references_lost="the watchdog expired", ecu_restart="the ECU restarted (heartbeat 251)")
    ev = book.review(_Status(faults, _Measured(0.0)), 0.01)
    assert ev is not None and ev["event"] == "fault" and ev["ack_required"]
    assert set(ev["new"]) == {"references_lost", "ecu_restart"}
    assert {f.name: f.reason for f in book.held} == {
        "references_lost": "the watchdog expired",
        "ecu_restart": "the ECU restarted (heartbeat 251)",
    }
    for k in range(50):  # latched: still there, never raised again, never cleared by fresh data
        now = 0.02 + 0.02 * k
        assert book.review(_Status(faults, _Measured(now)), now) is None
    assert len(book.held) == 2 and "faults/ack" in (book.refusal("goto") or "")


@pytest.mark.parametrize("seed", range(5))
def test_a_stale_measurement_clears_only_after_fresh_data_for_the_whole_clear_time(seed):
    """Random fresh/stale patterns sampled every 10 ms: the fault is released exactly when the data has been
    fresh without a break for FAULT_CLEAR_AFTER_S (within one sample), never earlier."""
    rng = np.random.default_rng(seed)
    book = FaultBook(STALE_S)
    now, fresh_since, cleared_at = 0.0, None, None
    assert book.review(_Status(_stale(), _Measured(-0.3)), now)["event"] == "fault"  # type: ignore[index]
    while cleared_at is None and now < 20.0:
        now += 0.01
        fresh = rng.random() < 0.97
        measured = _Measured(now if fresh else now - 0.5)
        ev = book.review(_Status(_stale(), measured), now)  # the link keeps it latched until re-armed
        if not fresh:
            fresh_since = None
        elif fresh_since is None:
            fresh_since = now
        if ev is not None:
            assert ev["event"] == "fault_cleared" and ev["cleared"] == ["stale_measurement"], ev
            cleared_at = now
            assert fresh_since is not None and now - fresh_since >= FAULT_CLEAR_AFTER_S - 1e-9
        else:
            assert fresh_since is None or now - fresh_since < FAULT_CLEAR_AFTER_S + 0.01 + 1e-9
    assert cleared_at is not None and not book
    # the link still latches it and its cause returns: raised again (not lost because it was cleared once)
    ev = book.review(_Status(_stale(), _Measured(now - 0.5)), now + 0.01)
    assert ev is not None and ev["new"] == ["stale_measurement"] and not ev["ack_required"]


def test_an_acknowledge_keeps_a_latched_fault_whose_cause_is_still_there():
    book = FaultBook(STALE_S)
    faults = _latched(address_lost="address 0x80 lost", references_lost="the watchdog expired")
    book.review(_Status(faults, _Measured(0.0)), 0.0)
    held_by = "NAME 0x1234 holds address 0x80"
    acked = book.acknowledge(_Status(faults, _Measured(0.0), fault_causes=("address_lost",), address_problem=held_by))
    assert acked == ("references_lost",)
    assert [(f.name, f.reason) for f in book.held] == [("address_lost", held_by)]
    assert book.cleared_event(acked) == {
        "event": "fault_cleared",
        "cleared": ["references_lost"],
        "by": "ack",
        "faults": ["address_lost"],
    }
    # acknowledged, then raised by the link again: new to the book, so a fault again
    ev = book.review(_Status(LinkFaults(references_lost=True), _Measured(1.0)), 1.0)
    assert ev is not None and ev["new"] == ["references_lost"]


def test_the_controllers_own_fault_latches_and_refuses_motion_naming_it():
    book = FaultBook(STALE_S)
    assert book.refusal("jog") is None and not book
    ev = book.hold(Fault("following_error", "lift +30 mrad from its reference", True, 1.0))
    assert ev == {
        "event": "fault",
        "faults": ["following_error"],
        "new": ["following_error"],
        "ack_required": True,
        "message": "lift +30 mrad from its reference",
    }
    why = book.refusal("jog")
    assert why is not None and why.startswith("jog refused: fault held: following_error (lift +30 mrad")
    assert "acknowledge following_error with faults/ack" in why
    assert book.review(_Status(LinkFaults(), _Measured(2.0)), 2.0) is None  # fresh data does not clear it
    assert book.acknowledge(_Status(LinkFaults(), _Measured(2.0))) == ("following_error",) and not book


def test_latch_link_takes_only_the_faults_that_do_not_clear_themselves():
    book = FaultBook(STALE_S)
    faults = LinkFaults(
        stale_measurement=True, bus_error=True, reasons=("3 sends failed",), reason_names=("bus_error",)
    )
    book.latch_link(_Status(faults, None), 0.0)
    assert [(f.name, f.reason, f.latches) for f in book.held] == [("bus_error", "3 sends failed", True)]


def test_a_reason_is_the_one_recorded_for_that_name_not_another_faults():
    faults = _latched(
        references_lost="references lost: the watchdog expired", stale_measurement="no valid measurement for 0.3 s"
    )
    st = _Status(faults, None)
    assert link_reason("stale_measurement", st) == "no valid measurement for 0.3 s"
    assert link_reason("ecu_heartbeat", st) == "references lost: the watchdog expired; no valid measurement for 0.3 s"


def test_a_stale_measurement_is_held_from_its_age_before_the_link_s_poll_latches_it():
    """A review: the link latches stale_measurement in its own poll; a cycle between the crossing and that poll
    said offline with no fault and the motion running. The book raises it from the measurement's age (its own
    reason), takes the link's reason once the link latches it (no second event), and clears it as any other.
    Before the first measurement nothing is raised (the link raises nothing then either)."""
    book = FaultBook(STALE_S)
    assert book.review(_Status(LinkFaults(), None), 5.0) is None  # no measurement yet: not a fault
    assert book.review(_Status(LinkFaults(), _Measured(0.0)), STALE_S) is None  # at the limit: fresh
    ev = book.review(_Status(LinkFaults(), _Measured(0.0)), 0.213)
    assert ev is not None and ev["new"] == ["stale_measurement"] and not ev["ack_required"], ev
    assert ev["message"] == "the ECU measurements are 0.213 s old (limit 0.2 s)"
    assert book.review(_Status(_stale(), _Measured(0.0)), 0.22) is None  # the link latched it: no new event
    assert [(f.name, f.reason) for f in book.held] == [("stale_measurement", "no valid cylinder positions for 0.3 s")]
    now = 0.3
    while book:  # fresh again: released after FAULT_CLEAR_AFTER_S
        now += 0.01
        ev = book.review(_Status(_stale(), _Measured(now)), now)
        assert now < 0.3 + FAULT_CLEAR_AFTER_S + 0.02
    assert ev is not None and ev["event"] == "fault_cleared", ev
