"""The black box records its own service's events and survives request floods (bridge.service.blackbox).

Fleet-trial defects: (1) the black box recorded whatever it heard on the public ``<prefix>/events`` key —
another tractor's login could forge entries, a router outage lost the events of its duration, a second
service on the prefix was recorded as this one; (2) 57876 refused ``ik`` requests of a viewer rotated
the whole log (start record and operator gotos included) away in about 20 s.

Truth: the events we make the service publish (a mode change we ask for) and the puts we forge; the
records we hand the log and the limits we set (a clock of our own: no timing assertions).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import zenoh

from bridge.service.blackbox import EventLog, RecordLimits, event_log_path, read_events
from bridge.service.config import ServiceConfig
from bridge.service.server import HitchService
from tests.helpers import loopback_client_session, wait_until
from tests.integration.service_process import ROOT, ROUTER, free_port


class _Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def _client(endpoint: str) -> zenoh.Session:
    return loopback_client_session(endpoint)


def _events(path, name: str) -> list[dict]:
    return [r for r in read_events(path) if r.get("kind") == "event" and r.get("event") == name]


# ---------------------------------------------------------------------------------------- own events
@pytest.mark.slow
def test_the_black_box_records_its_own_services_events_not_puts_on_the_public_key_and_not_through_the_router(
    tmp_path,
):
    """A service whose control core runs in its own process (the default), in client mode behind a router
    (as in the fleet trial). A put forged on ``<prefix>/events`` by another session is not recorded; the
    service's own events are, also while the router is down (before: the forged event was recorded as
    the service's own, and the events of an outage were lost)."""
    port = free_port()
    router_ep = f"tcp/127.0.0.1:{port}"
    router = subprocess.Popen([sys.executable, "-c", ROUTER, router_ep], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    svc = None
    log = None
    try:
        assert router.stdout is not None and "router ready" in router.stdout.readline()
        prefix = f"bbtest{port}/hitch"
        cfg = ServiceConfig(
            mode="client",
            connect=[router_ep],
            listen=[],
            prefix=prefix,
            data_dir=tmp_path,
            planning_processes=0,
            can_channel=f"bb-own-{port}",
        )
        svc = HitchService(cfg).start()
        assert svc.core is not None  # the control core has its own process: its events travel to the service
        path = event_log_path(tmp_path)
        log = EventLog(path)
        log.attach(svc)
        assert svc.api is not None

        forger = _client(router_ep)
        heard: list[bytes] = []
        sub = forger.declare_subscriber(f"{prefix}/events", lambda s: heard.append(s.payload.to_bytes()))
        try:
            forged = {"seq": 1, "event": "fault_cleared", "fault": "ecu_watchdog", "reason": "FORGED"}
            forger.put(f"{prefix}/events", json.dumps(forged))
            assert wait_until(lambda: any(b"FORGED" in h for h in heard), 10.0)  # the router passed it on
            # an event of the service's own, published after the forged one went through the router
            ok, reply = svc.api.handle("mode", b'{"mode": "manual"}', "alice")
            assert ok, reply
            assert wait_until(lambda: log.flush() and _events(path, "mode_changed"), 10.0)
        finally:
            sub.undeclare()
            forger.close()

        router.kill()  # SIGKILL: the outage of the trial
        router.wait(10)
        ok, reply = svc.api.handle("mode", b'{"mode": "auto"}', "alice")
        assert ok, reply
        assert wait_until(lambda: log.flush() and len(_events(path, "mode_changed")) >= 2, 10.0), read_events(path)

        recs = read_events(path)
        assert not any("FORGED" in json.dumps(r) for r in recs), [r for r in recs if "FORGED" in json.dumps(r)]
        modes = [r["mode"] for r in _events(path, "mode_changed")]
        assert modes[-2:] == ["manual", "auto"], modes
        seqs = [r["event_seq"] for r in recs if r.get("kind") == "event"]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)  # one service's numbering, in order
    finally:
        if log is not None:
            log.close()
        if svc is not None:
            svc.close()
        if router.poll() is None:
            router.kill()
        router.wait(10)


def test_a_core_note_with_an_event_reaches_the_services_event_listeners_without_zenoh():
    """The core hands each event it publishes to the service over its private socket (a note with the
    event's JSON); the service gives it to its in-process listeners — no Zenoh on the way."""
    svc = HitchService(ServiceConfig(planning_processes=0))
    heard: list[dict] = []
    svc.add_listener("event", heard.append)
    svc._core_note({"event": b'{"seq": 3, "t": 1.5, "event": "motion_finished", "motion_id": 9}'})
    svc._core_note({"event": b"{not json"})  # ignored, not raised into the core's reader thread
    assert heard == [{"seq": 3, "t": 1.5, "event": "motion_finished", "motion_id": 9}]


def test_events_that_did_not_reach_the_black_box_are_noted_as_a_gap(tmp_path):
    """The service numbers its events; a number skipped on the way (a bounded queue that overflowed, events
    published before the black box was attached) is written as a ``gap`` record naming the numbers."""

    class Service:
        def __init__(self) -> None:
            self.listeners: list = []
            self.api = None

        def add_listener(self, kind, cb):
            assert kind == "event"
            self.listeners.append(cb)

    path = event_log_path(tmp_path)
    svc = Service()
    with EventLog(path) as log:
        log.attach(svc)
        (cb,) = svc.listeners
        for seq in (3, 4, 5, 9, 10):  # 1, 2 before it was attached; 6..8 lost on the way
            cb({"seq": seq, "t": 1.0, "event": "fault", "fault": f"f{seq}"})
    recs = read_events(path)
    assert [(r["kind"], r.get("event_seq"), r.get("first_event_seq"), r.get("missing")) for r in recs] == [
        ("gap", None, 1, 2),
        ("event", 3, None, None),
        ("event", 4, None, None),
        ("event", 5, None, None),
        ("gap", None, 6, 3),
        ("event", 9, None, None),
        ("event", 10, None, None),
    ]
    assert recs[4]["last_event_seq"] == 8 and "6..8" in recs[4]["message"]


# ---------------------------------------------------------------------------------------- request floods
def test_a_flood_of_refused_requests_cannot_rotate_the_records_that_matter_out_of_the_log(tmp_path):
    """The trial's flood: refused ``ik`` requests of 8 unnamed sessions, here 60000 on a log of 3 files of
    50 kB. The start record, the operator's goto, a forbidden goto, the events and the stop record all
    survive; the refused requests are written a few at first and counted in ``suppressed`` records whose
    counts add up to every one of them (before: the flood rotated everything else away)."""
    path = event_log_path(tmp_path)
    n_flood = 60_000
    with EventLog(path, max_bytes=50_000, backup_count=2) as log:
        log.record("service", what="started")
        log.on_request("goto", "alice", b'{"goal": {"z": 0.2}}', True, {"motion_id": 1})
        log.on_request("goto", "bob", b'{"goal": {"z": 0.3}}', False, {"error": "forbidden", "message": "viewer"})
        for i in range(n_flood):
            log.on_request("ik", None, b'{"x": 0, "pppp": 1}', False, {"error": "invalid", "message": "pppp"})
            if i == n_flood // 2:
                log.on_event({"seq": 1, "t": 2.0, "event": "fault", "fault": "ecu_watchdog"})
                log.on_request("goto", "alice", b'{"goal": {"z": 0.1}}', True, {"motion_id": 2})
        log.summarize()  # as `hitch serve` does before its stop record
        log.record("service", what="stopped")
    recs = read_events(path)
    kinds = [(r["kind"], r.get("what") or r.get("event") or r.get("key")) for r in recs]
    assert kinds[0] == ("service", "started") and kinds[-1] == ("service", "stopped"), kinds[:5]
    gotos = [(r["user"], r["accepted"], r.get("motion_id")) for r in recs if r.get("key") == "goto"]
    assert gotos == [("alice", True, 1), ("bob", False, None), ("alice", True, 2)]
    assert ("event", "fault") in kinds
    written = [r for r in recs if r["kind"] == "request" and r["key"] == "ik"]
    summaries = [r for r in recs if r["kind"] == "suppressed"]
    assert len(written) < 100  # a few one by one …
    assert len(written) + sum(s["count"] for s in summaries) == n_flood  # … and every one counted
    s = summaries[0]
    assert (s["key"], s["user"], s["accepted"], s["error"]) == ("ik", None, False, "invalid")
    assert s["message"].startswith(f"{s['count']} further refused ik requests (invalid) from unnamed in the last")
    assert [r["seq"] for r in recs] == list(range(1, len(recs) + 1))  # nothing rotated away, nothing lost


def test_what_a_group_held_back_is_summarised_before_its_next_record_and_after_summary_s(tmp_path):
    """Per group (key, user, outcome, error): ``other_burst`` records one by one, then counted; the count is
    written as one ``suppressed`` record when the group's bucket lets a record through again (before that
    record) or when ``summary_s`` passed since the first held back (the writer's check), and at close.
    Accepted writing requests have their own, generous bucket; a group's flood takes nothing from another
    user's writing requests."""
    path = event_log_path(tmp_path)
    clock = _Clock()
    limits = RecordLimits(other_burst=2, other_per_s=0.5, total_burst=50, total_per_s=10.0, summary_s=30.0)
    refused = {"error": "forbidden", "message": "viewer"}
    with EventLog(path, limits=limits, clock=clock) as log:
        for _ in range(5):
            log.on_request("presets/save", "bob", b"{}", False, refused)
        for _ in range(20):
            log.on_request("jog", "alice", b'{"x": 1}', True, {})  # within write_burst: every one written
        assert log.flush()  # (the writer checks the summaries on our clock: written before we move it)
        clock.t += 2.0  # one token back: the next record of bob's group passes, after the summary of three
        log.on_request("presets/save", "bob", b"{}", False, refused)
        for _ in range(4):
            log.on_request("presets/save", "bob", b"{}", False, refused)  # no token left: held
        assert log.flush()
        clock.t += 31.0
        log.record("tick")  # the writer checks the due summaries after each record (and each second)
        assert log.flush()
        recs = read_events(path)
        sup = [r for r in recs if r["kind"] == "suppressed"]
        assert [s["count"] for s in sup] == [3, 4], sup
        assert recs.index(sup[0]) < len(recs) - 1 and recs[recs.index(sup[0]) + 1]["key"] == "presets/save"
        assert sum(1 for r in recs if r.get("key") == "jog") == 20
        log.on_request("presets/save", None, b"{}", False, refused)  # another group: its own budget
    recs = read_events(path)
    assert sum(1 for r in recs if r.get("key") == "presets/save" and r["kind"] == "request") == 2 + 1 + 1


def test_new_names_and_error_codes_cannot_multiply_the_budget(tmp_path):
    """A flood under ever new user names (where names are not checked) or error codes: all groups share
    one budget, beyond ``max_groups`` they are counted together (key and user ``*``), and the counts still
    add up to every request."""
    path = event_log_path(tmp_path)
    clock = _Clock()
    limits = RecordLimits(total_burst=20, total_per_s=1.0, max_groups=64, summary_s=10.0)
    n = 5000
    with EventLog(path, limits=limits, clock=clock) as log:
        for i in range(n):
            log.on_request("ik", f"user{i}", b"{}", False, {"error": f"e{i % 7}", "message": "no"})
    recs = read_events(path)
    written = [r for r in recs if r["kind"] == "request"]
    sup = [r for r in recs if r["kind"] == "suppressed"]
    assert len(written) == 20  # the shared budget, though each group's own bucket was full
    assert len(written) + sum(s["count"] for s in sup) == n
    assert len(sup) == 64 - 20 + 1  # the groups that held back, and the one of all the groups beyond
    (other,) = [s for s in sup if s["key"] == "*"]
    assert other["user"] == "*" and other["count"] == n - 64


def test_made_up_keys_filling_the_groups_never_silence_an_operator_s_accepted_commands(tmp_path):
    """A reviewer's find: once ``max_groups`` groups existed, a new group — an operator's accepted goto and
    stop too — went to the overflow, which is only counted; a viewer fills the groups with made-up keys
    (every key reaches the hook). Accepted writing requests now always keep a group of their own."""
    path = event_log_path(tmp_path)
    clock = _Clock()
    with EventLog(path, limits=RecordLimits(max_groups=64), clock=clock) as log:
        for i in range(64 * 20):  # 64 groups, each holding requests back (20 against a burst of 10)
            log.on_request(f"made/up{i % 64}", "viewer", b"{}", False, {"error": "unknown_key", "message": "no"})
        clock.t += 61.0  # past the summaries: the groups still hold counts (nothing pruned)
        for i in range(3):
            log.on_request("goto", "olga", b'{"goal": {"z": 0.1}}', True, {"accepted": True, "motion_id": i + 1})
            log.on_request("stop", "olga", b"{}", True, {"stopped": True})
    recs = [r for r in read_events(path) if r["kind"] == "request" and r.get("user") == "olga"]
    assert [r["key"] for r in recs] == ["goto", "stop"] * 3, recs


def test_accepted_writes_of_made_up_user_names_are_written_in_bounded_groups(tmp_path):
    """A review: accepted writing requests bypassed the group cap, so made-up user names (user keys without a
    router that checks them) grew the groups without bound. Beyond 4 × max_groups they share one group, still
    written."""
    from bridge.service.blackbox import KEPT_GROUPS_FACTOR

    path = event_log_path(tmp_path)
    with EventLog(path, limits=RecordLimits(max_groups=4), clock=_Clock()) as log:
        for i in range(40):
            log.on_request("goto", f"made-up-{i}", b"{}", True, {"accepted": True, "motion_id": i + 1})
        groups = len(log._limiter._groups)
    assert groups <= 4 * KEPT_GROUPS_FACTOR + 1, groups
    written = [r for r in read_events(path) if r["kind"] == "request"]
    assert len(written) == 40  # within the shared group's burst: every one written


def test_record_limits_out_of_range_are_refused_by_name():
    from bridge.service.blackbox import BlackBoxError

    with pytest.raises(BlackBoxError, match=r"RecordLimits.other_burst must be an integer"):
        RecordLimits(other_burst=0)
    with pytest.raises(BlackBoxError, match=r"RecordLimits.summary_s must be a number"):
        RecordLimits(summary_s=float("nan"))


# ---------------------------------------------------------------------------------------- what was changed
def _write_body(key: str) -> bytes:
    """A body that changes something on ``key`` (``mode`` and ``work/settings`` read without a value)."""
    if key == "mode":
        return b'{"mode": "manual"}'
    if key == "work/settings":
        return b'{"draft_setpoint_n": 25000.0}'
    return json.dumps({"marker": key}).encode()


def test_every_motion_and_write_key_of_the_access_control_is_kept_with_its_body(tmp_path):
    """A field trial: ``goto`` records carried their body, but hitch/raise|return, work/…, implements/…,
    lines/…, track/start did not, and their accepted requests were limited as reads (10, then one per 10 s):
    the black box's own key list had fallen behind the access control's. Every operator key (security's
    MOTION_KEYS, WRITE_KEYS, any key under WRITE_PREFIXES, and every API key the access control calls a write)
    is now kept, each of its accepted requests written with its body."""
    from bridge.service.schemas import REQUESTS
    from bridge.service.security import MOTION_KEYS, WRITE_KEYS, WRITE_PREFIXES, key_access

    api_writes = {k for k in REQUESTS if key_access(k) == "write"}
    from bridge.service.blackbox import STREAMED_KEYS  # the setpoint stream: limited as reads (the test below)

    keys = sorted(
        (set(MOTION_KEYS) | set(WRITE_KEYS) | api_writes | {f"{p}start" for p in WRITE_PREFIXES}) - STREAMED_KEYS
    )
    assert {"hitch/raise", "work/settings", "implements/lock", "lines/save", "track/start"} <= set(keys)
    path = event_log_path(tmp_path)
    # reads sparingly (one record per group): a key limited as a read would lose its second and third request
    limits = RecordLimits(other_burst=1, other_per_s=0.001, total_burst=1, total_per_s=0.001)
    with EventLog(path, limits=limits, clock=_Clock()) as log:
        for i in range(3):
            for key in keys:
                reply = {"accepted": True, "motion_id": i + 1}
                if key == "work/settings":
                    reply = {"implement": "default", "saved": True, "settings": {}, "status": {}}
                log.on_request(key, "olga", _write_body(key), True, reply)
    recs = [r for r in read_events(path) if r["kind"] == "request"]
    assert not [r for r in read_events(path) if r["kind"] == "suppressed"]
    for key in keys:
        mine = [r for r in recs if r["key"] == key]
        assert len(mine) == 3, (key, mine)
        assert all(r.get("request") == _write_body(key).decode() and not r.get("read") for r in mine), mine
    from bridge.service.blackbox import is_writing_key  # the rule itself, for keys added later

    assert all(is_writing_key(k) for k in keys), [k for k in keys if not is_writing_key(k)]


def test_work_status_reads_never_crowd_out_a_settings_write_and_read_apart_from_it(tmp_path):
    """The field trial: 15 ``hitch work status`` (work/settings without a setting) and then one write of 25 kN
    left 10 records, each ``request work/settings by -: accepted``, and not the write: it fell in the reads'
    bucket. Reads are now their own group, limited as reads and marked ``read``; the write is kept, with its
    body."""
    from bridge.cli.records import format_record

    path = event_log_path(tmp_path)
    status = {"implement": "default", "settings": {"mode": "draft"}, "status": {"running": False}}
    with EventLog(path, clock=_Clock()) as log:
        for i in range(15):
            log.on_request("work/settings", None, b"{}" if i % 2 else b"", True, status)
        log.on_request("work/settings", None, b'{"draft_setpoint_n": 25000.0}', True, {**status, "saved": True})
        # the same decided from the body where there is no settings reply (a refusal): null slip_limit changes
        log.on_request("work/settings", None, b'{"slip_limit": null}', False, {"error": "busy", "message": "x"})
        log.on_request("work/settings", None, b'{"mode": null}', False, {"error": "busy", "message": "x"})
        log.on_request("mode", "olga", b"", True, {"mode": "auto", "modes": []})  # a read of the mode
        log.on_request("mode", "olga", b'{"mode": "manual"}', True, {"mode": "manual", "modes": []})
    recs = read_events(path)
    reqs = [r for r in recs if r["kind"] == "request" and r["key"] == "work/settings" and r["accepted"]]
    reads = [r for r in reqs if r.get("read")]
    writes = [r for r in reqs if not r.get("read")]
    assert len(reads) == 10 and len(writes) == 1, reqs
    assert json.loads(writes[0]["request"]) == {"draft_setpoint_n": 25000.0}
    (sup,) = [r for r in recs if r["kind"] == "suppressed"]
    assert sup["key"] == "work/settings" and sup["count"] == 5 and sup["read"] is True and "reads" in sup["message"]
    refused = [r for r in recs if r["kind"] == "request" and r["key"] == "work/settings" and not r["accepted"]]
    assert [bool(r.get("read")) for r in refused] == [False, True]
    modes = [r for r in recs if r["kind"] == "request" and r["key"] == "mode"]
    assert [bool(r.get("read")) for r in modes] == [True, False] and json.loads(modes[1]["request"]) == {
        "mode": "manual"
    }
    assert "read only" in format_record(reads[0]) and "read only" not in format_record(writes[0])
    assert "25000" in format_record(writes[0])


def test_streamed_setpoints_are_limited_as_reads_while_their_session_start_is_kept(tmp_path):
    """track/setpoint is a write (under track/), but it streams at up to 100 Hz for hours: kept as generously as
    a goto it would fill the log at about 2 records a second. It is limited as reads are; track/start is kept."""
    from bridge.service.blackbox import is_writing_key

    assert not is_writing_key("track/setpoint") and is_writing_key("track/start") and is_writing_key("track/stop")
    path = event_log_path(tmp_path)
    limits = RecordLimits(other_burst=5, other_per_s=0.001, total_burst=5, total_per_s=0.001)
    with EventLog(path, limits=limits, clock=_Clock()) as log:
        log.on_request("track/start", "olga", b'{"dof": ["z"]}', True, {"accepted": True, "session": 3})
        for seq in range(300):
            body = json.dumps({"session": 3, "seq": seq, "pose": {"z": 0.1}}).encode()
            log.on_request("track/setpoint", "olga", body, True, {"accepted": True})
        log.on_request("track/stop", "olga", b'{"session": 3}', True, {"stopping": True})
    recs = read_events(path)
    setpoints = [r for r in recs if r["kind"] == "request" and r["key"] == "track/setpoint"]
    assert len(setpoints) == 5, len(setpoints)  # the reads' burst, then counted
    held = sum(r.get("count", 0) for r in recs if r["kind"] == "suppressed" and r.get("key") == "track/setpoint")
    assert held == 295, [r for r in recs if r["kind"] == "suppressed"]
    assert [r["key"] for r in recs if r["kind"] == "request" and r["key"] != "track/setpoint"] == [
        "track/start",
        "track/stop",
    ]


def test_a_summary_of_under_ten_seconds_says_its_window_to_a_tenth(tmp_path):
    """A newcomer's held jog: each summary said "4 further accepted jog requests from unnamed in the last 0 s"
    (a 0.4 s window rounded to whole seconds)."""
    path = event_log_path(tmp_path)
    clock = _Clock()
    limits = RecordLimits(other_burst=1, other_per_s=2.5, total_burst=50, total_per_s=10.0)
    refused = {"error": "forbidden", "message": "viewer"}
    with EventLog(path, limits=limits, clock=clock) as log:
        log.on_request("presets/save", "bob", b"{}", False, refused)  # the burst
        log.on_request("presets/save", "bob", b"{}", False, refused)  # held back at t
        clock.t += 0.4  # one token back: the next passes, after the summary of one over 0.4 s
        log.on_request("presets/save", "bob", b"{}", False, refused)
    (sup,) = [r for r in read_events(path) if r["kind"] == "suppressed"]
    assert sup["window_s"] == pytest.approx(0.4) and sup["message"].endswith("in the last 0.4 s"), sup
