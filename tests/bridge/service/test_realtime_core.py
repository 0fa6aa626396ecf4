"""The service's real-time core in simulated time: events numbered and in order, deadlines instead of
late execution, a stop that cancels what is queued and takes any payload, admission control of
expensive requests, the fault policy (self-clearing vs latched until ``faults/ack``), nothing
recomputed at rest, and the twin's fault injection through the API.

Truth used: the order in which the test itself made things happen (a cycle run inside an event
delivery happens after the motion started), the request's own deadline and arrival time, the
written fault policy (``docs/faults.md``), and call counts of the exact inverse.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from bridge.service.api import MAX_IN_FLIGHT_PER_USER
from bridge.service.motion.controller import STOP_GRACE_S
from bridge.service.motion.types import FAULT_CLEAR_AFTER_S, MotionError
from planner.ik_qp.hitch_ik import IKSolver
from planner.limits.guard import Guard
from planner.trajectory import TrajectoryPlanner
from tests.helpers import Gate, SimService

DT = 0.02


class Rig(SimService):
    """A controller and its API on a simulated rig; cycles driven by the test every 20 ms."""

    def __init__(self, model, tmp_path, *, plan_guard=None, sim_fault=None):
        super().__init__(
            model,
            tmp_path / "hitch.sqlite3",
            ik=IKSolver(model),
            plan_guard=plan_guard,
            settle_s=0.1,
            sim_fault=sim_fault,
        )

    def run(self, seconds: float, *, ecu: bool = True) -> None:  # type: ignore[override]
        end = self.rig.now_s + seconds
        while self.rig.now_s < end - 1e-9:
            t = self.rig.now_s + DT
            if ecu:
                self.rig.run_until(t)
            else:  # the ECU falls silent: only the link runs
                while self.rig.now_s < t - 1e-9:
                    self.rig._k += 1
                    self.rig.link.poll(self.rig.now_s)
            self.mc.cycle()

    def names(self) -> list[str]:
        return [e["event"] for e in self.events]


@pytest.fixture
def r(model, tmp_path):
    rig = Rig(model, tmp_path)
    yield rig
    rig.close()


# ---------------------------------------------------------------------------- events in order
def test_events_are_numbered_and_never_overtake_each_other(r):
    """A control cycle that runs while the requester is still delivering its events (here: inside
    the delivery of the first one) must not get its ``motion_finished`` out before the requester's
    ``motion_started``. Fails on the old code (events emitted after the lock, by each thread)."""
    r.mc.goto({"z": 0.25})
    r.run(0.3)  # moving: the next goto replaces it (events: aborted, started)
    nested = {"done": False}

    def deliver(e):
        r.events.append(e)
        if e["event"] == "motion_aborted" and not nested["done"]:
            nested["done"] = True
            r.run(8.0)  # the control thread runs on and finishes the new motion meanwhile

    r.mc.outbox._on_event = deliver  # the listener that interleaves
    acc = r.mc.goto({"z": 0.24})
    mine = [e["event"] for e in r.events if e.get("motion_id") == acc.motion_id]
    assert mine[:2] == ["motion_started", "motion_finished"], mine
    seqs = [e["seq"] for e in r.events]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert seqs == list(range(1, len(seqs) + 1))  # one per event, none lost


# ---------------------------------------------------------------------------- deadlines, stop
def test_a_goto_that_waited_past_its_deadline_is_refused_not_run_later(r):
    """The old defect: a goto stuck behind slow requests started long after its client gave up.
    Arriving 6 s ago with the default 1 s deadline it is refused ``busy``; nothing moves."""
    ok, reply = r.call("goto", {"goal": {"z": 0.2}}, received=time.monotonic() - 6.0)
    assert not ok and reply["error"] == "busy" and "deadline" in reply["message"], reply
    r.run(0.5)
    assert "motion_started" not in r.names() and not r.states[-1]["moving"]
    ok, reply = r.call("goto", {"goal": {"z": 0.2}, "deadline_ms": 10_000}, received=time.monotonic() - 6.0)
    assert ok, reply  # its own, longer deadline: still in time


def test_a_stop_cancels_every_motion_request_that_arrived_before_it(r):
    queued = time.monotonic()  # a goto and a maneuver run waiting in a queue ...
    r.store.save_maneuver("m", "steps:\n  - goto: {z: 0.2}\n")
    ok, _ = r.call("stop", {})  # ... when the operator stops (the hitch is at rest)
    stopped = time.monotonic()  # the stop took effect before this
    assert ok
    for key, body in (
        ("goto", {"goal": {"z": 0.2}}),
        ("maneuvers/run", {"name": "m"}),
        ("jog", {"vz": 0.02, "ttl_ms": 3000}),  # a jog checked its deadline only: it ran after the stop
    ):
        ok, reply = r.call(key, body, received=queued)
        assert not ok and reply["error"] == "busy" and "stop" in reply["message"], reply
    r.run(0.5)
    assert "motion_started" not in r.names()
    # arrived within STOP_GRACE_S of it: maybe sent before (its arrival given: the simulated run above takes real
    # time, on a loaded computer more than STOP_GRACE_S — the test failed so)
    ok, reply = r.call("goto", {"goal": {"z": 0.2}}, received=stopped + 0.2 * STOP_GRACE_S)
    assert not ok and reply["error"] == "busy" and "after a stop" in reply["message"], reply
    assert "send it again" in reply["message"]
    time.sleep(STOP_GRACE_S + 0.02)
    ok, reply = r.call("goto", {"goal": {"z": 0.2}})  # sent after the stop: runs
    assert ok, reply


_TWO_STEPS = "steps:\n  - goto: {z: 0.3}\n  - wait: 30\n  - goto: {z: 0.0}\n"


def _paused(r):
    """A maneuver paused in its first step, the hitch braked to rest and holding."""
    r.store.save_maneuver("m", _TWO_STEPS)
    assert r.call("maneuvers/run", {"name": "m"})[0]
    r.run(0.6)
    assert r.call("maneuvers/pause")[0]
    r.run(2.0)
    return r.states[-1]["pose"]["z"]


@pytest.mark.parametrize("action", ["resume", "skip"])
def test_a_maneuver_resume_or_skip_that_waited_past_its_deadline_is_refused_not_run_later(r, action):
    """Resume and skip start the next motion; they came without a deadline and ran whenever a worker took
    them (fails on the old code: the 6 s old request resumed the maneuver)."""
    held = _paused(r)
    ok, reply = r.call(f"maneuvers/{action}", {}, received=time.monotonic() - 6.0)
    assert not ok and reply["error"] == "busy" and "deadline" in reply["message"], reply
    r.run(1.0)
    assert abs(r.states[-1]["pose"]["z"] - held) < 2e-3 and not r.states[-1]["moving"]
    assert r.states[-1]["maneuver"]["paused"] is True and r.states[-1]["maneuver"]["step"] == 0
    ok, reply = r.call(f"maneuvers/{action}", {"deadline_ms": 10_000}, received=time.monotonic() - 6.0)
    assert ok, reply  # its own, longer deadline: in time


def test_a_stop_cancels_a_resume_or_a_track_start_that_arrived_before_it(r):
    _paused(r)
    queued = time.monotonic()  # a resume and a track start waiting ...
    assert r.call("stop", {})[0]  # ... when the operator stops
    for key, body in (("maneuvers/resume", {}), ("maneuvers/skip", {}), ("track/start", {"dof": ["z"]})):
        ok, reply = r.call(key, body, received=queued)
        assert not ok and reply["error"] == "busy" and "stop" in reply["message"], (key, reply)
    ok, reply = r.call("track/start", {"dof": ["z"]}, received=queued - 6.0)
    assert not ok and reply["error"] == "busy", reply
    time.sleep(STOP_GRACE_S + 0.02)
    ok, reply = r.call("track/start", {"dof": ["z"]})  # sent after the stop: starts
    assert ok, reply


def test_a_track_start_that_waited_past_its_deadline_is_refused(r):
    ok, reply = r.call("track/start", {"dof": ["z"]}, received=time.monotonic() - 2.0)
    assert not ok and reply["error"] == "busy" and "deadline" in reply["message"], reply
    assert "motion_started" not in r.names()
    ok, reply = r.call("track/start", {"dof": ["z"], "deadline_ms": 5000}, received=time.monotonic() - 2.0)
    assert ok, reply


def test_the_step_a_resume_leads_to_must_start_by_its_deadline(model, tmp_path):
    """A new user's report: a resume with deadline_ms 1 was taken, and its step moved 17 ms later. The step's
    plan (at the next cycle) now keeps the resume's deadline: planning that takes 1.5 s (of the rig's time)
    against 1 s aborts the maneuver (``deadline``) and nothing moves; with 5 s it runs."""
    slow = {"on": False}

    class SlowGuard(Guard):
        def plan(self, *a, **k):
            if slow["on"]:
                rig.rig.run_until(rig.rig.now_s + 1.5)
            return super().plan(*a, **k)

    rig = Rig(model, tmp_path, plan_guard=SlowGuard(TrajectoryPlanner(model)))
    try:
        for deadline_ms, runs in ((1000, False), (5000, True)):
            slow["on"] = False
            held = _paused(rig)
            n_started = rig.names().count("motion_started")
            slow["on"] = True
            ok, reply = rig.call("maneuvers/resume", {"deadline_ms": deadline_ms})
            assert ok, reply  # taken in time; its step is planned at the next cycle
            rig.run(0.5)
            started = rig.names().count("motion_started") - n_started
            aborted = [e for e in rig.events if e["event"] == "maneuver_aborted"]
            if runs:
                assert started == 1 and not aborted[1:], aborted
            else:
                assert started == 0 and aborted[-1]["reason"] == "deadline", aborted
                assert "deadline" in aborted[-1]["message"], aborted[-1]
                assert abs(rig.states[-1]["pose"]["z"] - held) < 2e-3 and not rig.states[-1]["moving"]
            assert rig.call("stop", {})[0]
            rig.run(3.0)
    finally:
        rig.close()


def test_a_plan_that_cannot_start_by_the_deadline_is_refused(model, tmp_path):
    class SlowGuard(Guard):  # planning takes 1.5 s of the rig's time
        def plan(self, *a, **k):
            rig.rig.run_until(rig.rig.now_s + 1.5)
            return super().plan(*a, **k)

    rig = Rig(model, tmp_path, plan_guard=SlowGuard(TrajectoryPlanner(model)))
    try:
        with pytest.raises(MotionError) as ei:
            rig.mc.goto({"z": 0.2}, deadline=rig.rig.now_s + 1.0)
        assert ei.value.code == "busy" and "deadline" in str(ei.value)
        rig.run(0.5)
        assert "motion_started" not in rig.names()
        acc = rig.mc.goto({"z": 0.2}, deadline=rig.rig.now_s + 3.0)  # a deadline it can keep
        assert acc.motion_id > 0
    finally:
        rig.close()


def test_a_goto_does_not_wait_for_a_busy_planner_past_its_deadline(r):
    """The planning lock is held (four slow plans); the goto gives up at its deadline (wall time)."""
    assert r.mc._plan_lock.acquire(timeout=1.0)
    try:
        t0 = time.monotonic()
        ok, reply = r.call("goto", {"goal": {"z": 0.2}, "deadline_ms": 200})
        took = time.monotonic() - t0
    finally:
        r.mc._plan_lock.release()
    assert not ok and reply["error"] == "busy", reply
    assert took < 5.0  # it gave up (0.2 s plus scheduling), it did not wait for the planner
    r.run(0.3)
    assert "motion_started" not in r.names()


@pytest.mark.parametrize("payload", [b"", b"{}", b'{"why": "because"}', b"not json at all {", b"\xff\xfe", b"[1,2]"])
def test_any_payload_sent_to_stop_stops(r, payload):
    r.mc.goto({"z": 0.25})
    r.run(0.4)
    ok, reply = r.call("stop", payload)
    assert ok and reply["stopped"] and reply["motion_id"] is not None, reply
    r.run(2.0)
    assert any(e["event"] == "motion_finished" and e["motion_id"] == reply["motion_id"] for e in r.events)


def test_expensive_requests_are_admitted_a_few_per_user(r):
    r.mc.preview_with_tail = held = Gate(r.mc.preview_with_tail, wait_s=5.0)
    entered = held.entered
    body = {"goal": {"z": 0.2}}
    results: list = []
    ts = [
        threading.Thread(target=lambda: results.append(r.call("plan", body, user=None)))
        for _ in range(MAX_IN_FLIGHT_PER_USER)
    ]
    for t in ts:
        t.start()
    for _ in ts:
        assert entered.acquire(timeout=5.0)
    try:
        ok, reply = r.call("plan", body)  # one more of the same user: at once busy
        assert not ok and reply["error"] == "busy" and "at a time" in reply["message"], reply
        # anonymous requests share one allowance, and say so (a fleet trial read "of this client" while its own
        # client had none running)
        assert "of clients without a user name (they share one allowance" in reply["message"], reply
        ok, reply = r.call("maneuvers/validate", {"script": "steps: [{wait: 1}]"})
        assert not ok and reply["error"] == "busy"
        # a save parses its script as validate does, on the service's threads: within the same allowance (six
        # clients flooding saves of deeply nested scripts held presets/list 4.6 s; a trial)
        ok, reply = r.call("maneuvers/save", {"name": "held", "script": "steps: [{wait: 1}]"})
        assert not ok and reply["error"] == "busy" and "maneuvers/save" in reply["message"], reply
        # another user is admitted meanwhile: the limit is per user, not the service's
        other = threading.Thread(target=lambda: results.append(r.call("plan", body, user="alice")))
        other.start()
        ts.append(other)
        assert entered.acquire(timeout=5.0), "the other user's plan was not admitted"
        ok, _ = r.call("stop", {})  # cheap requests are not held back
        assert ok
    finally:
        held.open()
        for t in ts:
            t.join(10.0)
    assert all(ok for ok, _ in results)
    ok, _ = r.call("plan", body)  # answered ones free their slot
    assert ok
    ok, reply = r.call("maneuvers/save", {"name": "held", "script": "steps: [{wait: 1}]"})
    assert ok and reply["saved"] == "held", reply


# ---------------------------------------------------------------------------- fault policy
def test_a_stale_measurement_clears_itself_with_an_event_and_never_resumes(r):
    """ECU silent while holding (a loaded computer, a loose plug): the fault is raised, the hold
    dropped; once the data is fresh again it clears itself with an event (not silently by the next
    goto), and nothing moves until a new command."""
    acc = r.mc.goto({"z": 0.22})
    r.run(acc.duration + 0.3)
    assert r.rig.link.streaming  # holding the final pose
    r.run(0.4, ecu=False)
    faults = [e for e in r.events if e["event"] == "fault"]
    assert faults and "stale_measurement" in faults[0]["new"] and not any(f["ack_required"] for f in faults)
    assert not r.rig.link.streaming and "stale_measurement" in r.states[-1]["ecu"]["faults"]
    with pytest.raises(MotionError) as ei:  # while the fault is held: no motion
        r.mc.goto({"z": 0.1})
    assert ei.value.code == "ecu" and "stale_measurement" in str(ei.value)
    r.run(FAULT_CLEAR_AFTER_S + 1.2)  # data fresh again (the heartbeat recovers after 8 in sequence)
    cleared = [e for e in r.events if e["event"] == "fault_cleared"]
    assert cleared and "stale_measurement" in cleared[-1]["cleared"] and cleared[-1]["by"] == "fresh data"
    assert r.states[-1]["ecu"]["faults"] == [] and not r.rig.link.streaming  # nothing resumed
    assert cleared[-1]["seq"] > faults[-1]["seq"]
    r.mc.goto({"z": 0.1})  # a new command moves again


def test_no_state_says_offline_without_the_fault_that_takes_it_offline(r):
    """Each state message is one moment: the cycle in which the measurement crossed its age limit said
    ``online: false`` with ``faults: []`` and a motion still running (the fault came one message later; CI's
    browser test read that message). Cycle by cycle while the ECU falls silent during a goto: whenever a
    state says offline, it holds ``stale_measurement`` and no motion."""
    acc = r.mc.goto({"z": 0.22})
    r.run(0.2)
    assert r.states[-1]["moving"], acc
    first = len(r.states)
    r.run(0.4, ecu=False)
    seen = r.states[first:]
    offline = [s for s in seen if not s["ecu"]["online"]]
    assert offline, [s["ecu"] for s in seen]  # the silence did take it offline
    for s in offline:
        assert "stale_measurement" in s["ecu"]["faults"], s["ecu"]
        assert not s["moving"] and s["motion"] is None, s


@pytest.mark.parametrize("phase_ms", [3, 7])
def test_no_state_says_offline_without_its_fault_when_the_link_polls_on_its_own_schedule(r, phase_ms):
    """As the test above, with the link polled as in the service: by its own thread every 10 ms
    (``check_period_s``), not just before each control cycle (a review: a cycle between the crossing and the
    link's poll still said offline with no fault and the motion running; the fault book now raises it from the
    measurement's age). Truth: the state's own ``online`` flag."""
    acc = r.mc.goto({"z": 0.22})
    r.run(0.2)
    assert r.states[-1]["moving"], acc
    rig = r.rig
    for _ in range(phase_ms):  # the control cycle's phase against the ECU's frames and the link's polls
        rig.tick()
    first, first_event = len(r.states), len(r.events)
    end = rig.now_s + 0.4
    while rig.now_s < end - 1e-9:  # the ECU falls silent
        t = rig.now_s + DT
        while rig.now_s < t - 1e-9:
            rig._k += 1  # noqa: SLF001 — the rig's clock, as Rig.run
            if rig._k % 10 == 0:  # noqa: SLF001
                rig.link.poll(rig.now_s)
        r.mc.cycle()
    offline = [s for s in r.states[first:] if not s["ecu"]["online"]]
    assert offline
    for s in offline:
        assert "stale_measurement" in s["ecu"]["faults"], (s["ecu"], s["moving"])
        assert not s["moving"], s
    # the link's own reason once it latched it (it names the sender and why), one fault event
    held = {f.name: f.reason for f in r.mc.faults}
    assert "address" in held["stale_measurement"], held
    assert sum("stale_measurement" in e["new"] for e in r.events[first_event:] if e["event"] == "fault") == 1


def test_a_latched_fault_needs_an_acknowledge(r):
    """An internal error (a bug in a cycle) latches: motion is refused naming faults/ack until an
    operator acknowledges it; the ack is an event and nothing resumes by itself."""
    r.mc.goto({"z": 0.25})
    r.run(0.3)
    boom = RuntimeError("injected")

    def broken(*a, **k):
        raise boom

    real, r.mc.planner.inverse.solve_full = r.mc.planner.inverse.solve_full, broken
    try:
        r.mc._thread = None
        try:
            r.mc.cycle()
        except RuntimeError as exc:  # the periodic thread hands it to on_error
            r.mc._on_cycle_error(exc)
    finally:
        r.mc.planner.inverse.solve_full = real
    assert r.names()[-1] == "fault" and r.events[-1]["ack_required"]
    r.run(1.0)
    assert r.states[-1]["ecu"]["ack_required"] == ["internal"] and not r.states[-1]["moving"]
    ok, reply = r.call("goto", {"goal": {"z": 0.1}})
    assert not ok and reply["error"] == "ecu" and "faults/ack" in reply["message"], reply
    ok, reply = r.call("jog", {"vz": 0.01})
    assert not ok and reply["error"] == "ecu"
    ok, reply = r.call("faults/ack", {})
    assert ok and reply["acknowledged"] == ["internal"] and reply["faults"] == [], reply
    assert r.events[-1]["event"] == "fault_cleared" and r.events[-1]["by"] == "ack"
    r.run(0.5)
    assert not r.states[-1]["moving"] and r.states[-1]["ecu"]["faults"] == []  # nothing resumed
    ok, reply = r.call("goto", {"goal": {"z": 0.1}})
    assert ok, reply


def test_the_written_fault_policy_is_the_one_the_controller_applies():
    """docs/faults.md's table names every fault the link can raise plus the controller's own (``internal``,
    ``following_error``), each with the kind the controller gives it (self-clearing: SELF_CLEARING_FAULTS;
    latching: every other) and the clearing delay."""
    import re
    from dataclasses import fields
    from pathlib import Path

    from bridge.link.state import LinkFaults
    from bridge.service.motion.following import FOLLOWING_ERROR
    from bridge.service.motion.types import SELF_CLEARING_FAULTS

    text = (Path(__file__).resolve().parents[3] / "docs" / "faults.md").read_text(encoding="utf-8")
    rows = dict(re.findall(r"^\| `([a-z_]+)` \|[^|]*\| (self-clearing|latching) \|", text, re.MULTILINE))
    link_faults = set(LinkFaults.names())
    assert link_faults == {f.name for f in fields(LinkFaults) if f.type in ("bool", bool)}  # every boolean field
    assert set(rows) == link_faults | {"internal", FOLLOWING_ERROR}, sorted(rows)
    assert {n for n, kind in rows.items() if kind == "self-clearing"} == set(SELF_CLEARING_FAULTS)
    assert f"fresh for {FAULT_CLEAR_AFTER_S:g} s" in text


def test_faults_ack_is_for_operators_only(model, tmp_path):
    from bridge.service.security import AccessPolicy

    rig = Rig(model, tmp_path)
    try:
        rig.api.policy = AccessPolicy(operators=("op",), viewers=("viewer",))
        for key in ("faults/ack", "sim/fault"):
            ok, reply = rig.call(key, {}, user="viewer")
            assert not ok and reply["error"] == "forbidden", reply
        ok, _ = rig.call("faults/ack", {}, user="op")
        assert ok
    finally:
        rig.close()


# ---------------------------------------------------------------------------- idle cost
def test_nothing_is_recomputed_at_rest(r):
    acc = r.mc.goto({"z": 0.2})
    r.run(acc.duration + 0.5)  # finished: holding the final pose
    assert not r.states[-1]["moving"] and r.rig.link.streaming
    inv = r.mc.planner.inverse
    calls = {"n": 0}
    real = inv.solve_full

    def counting(*a, **k):
        calls["n"] += 1
        return real(*a, **k)

    inv.solve_full = counting
    try:
        r.run(0.3)  # the measured pose settles
        n0, e0, s0 = calls["n"], r.mc._eval_cache.evaluations, len(r.states)
        sent0 = r.rig.link.counters.references_tx
        r.run(2.0)  # 100 idle cycles
    finally:
        inv.solve_full = real
    assert len(r.states) - s0 == 100  # the state is still published at its rate
    assert calls["n"] - n0 == 0, "the held reference was recomputed"
    assert r.mc._eval_cache.evaluations - e0 <= 4, "guard evaluations repeated at an unchanged pose"
    assert r.rig.link.counters.references_tx - sent0 >= 95  # the link streams the held reference on its own
    held = r.states[-1]["reference"]["pose"]
    assert held["z"] == pytest.approx(0.2, abs=1e-9)


# ---------------------------------------------------------------------------- fault injection
def test_sim_fault_without_a_simulated_ecu_is_unavailable(r):
    ok, reply = r.call("sim/fault", {"cut": "both"})
    assert not ok and reply["error"] == "unavailable" and "simulated ECU" in reply["message"], reply


def test_sim_fault_reaches_the_twin(model, tmp_path):
    rig = Rig(model, tmp_path)
    rig.api.sim_fault = rig.rig.node.apply_fault
    try:
        ok, reply = rig.call("sim/fault", {"cut": "planner_to_ecu", "loss": 0.0, "delay_ms": 0})
        assert ok and reply["applied"]["cut"] == "planner_to_ecu", reply
        ok, reply = rig.call("sim/fault", {"cut": "sideways"})
        assert not ok and reply["error"] == "bad_request" and "cut" in reply["message"]
        ok, _ = rig.call("sim/fault", {})  # no fault
        assert ok
    finally:
        rig.close()


def test_a_one_way_loss_injected_in_the_twin_aborts_and_nothing_moves_after_it(model, tmp_path):
    """planner → ECU cut while moving: the link's ``references_lost`` (or any fault) aborts the
    motion; when frames flow again nothing moves without a new command (and, the fault latching,
    not before an acknowledge)."""
    rig = Rig(model, tmp_path)
    rig.api.sim_fault = rig.rig.node.apply_fault
    try:
        acc = rig.mc.goto({"z": 0.28})
        rig.run(0.5)
        rig.call("sim/fault", {"cut": "planner_to_ecu"})  # references stop arriving at the ECU
        rig.run(0.6)
        faults = [e for e in rig.events if e["event"] == "fault"]
        assert faults, "one-way loss not detected"
        aborted = [e for e in rig.events if e["event"] == "motion_aborted"]
        assert aborted and aborted[-1]["motion_id"] == acc.motion_id
        rig.call("sim/fault", {"cut": "none"})
        z0 = rig.rig.link.latest_state().pose.z
        rig.run(2.0)  # the link is back: nothing moves without a new command
        assert abs(rig.rig.link.latest_state().pose.z - z0) < 2e-3
        assert not rig.states[-1]["moving"]
        if faults[-1]["ack_required"]:
            assert not rig.call("goto", {"goal": {"z": 0.1}})[0]
            assert rig.call("faults/ack", {})[0]
        ok, reply = rig.call("goto", {"goal": {"z": 0.1}})
        assert ok, reply
        rig.run(3.0)
        assert np.isclose(rig.states[-1]["reference"]["pose"]["z"], 0.1, atol=1e-9)
    finally:
        rig.close()
