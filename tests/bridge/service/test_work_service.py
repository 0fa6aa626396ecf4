"""Work control in the live service (bridge.service.work): ``work/settings`` round trip through
``ServiceAPI.handle`` (validated naming field and range, persisted per implement, following the selected
implement), a work session on the simulated rig in simulated time whose draft demand beyond the depth
and workspace limits is clipped and named, and — with the core in its own process (the default) — a
draft session over a simulated field that holds the draft far closer to its setpoint than position
control, and the fallback with one ``work_fallback`` event when there is no draft on the bus."""

from __future__ import annotations

import itertools
import json
import time

import numpy as np
import pytest

from bridge.service.config import ServiceConfig
from bridge.service.motion.controller import STOP_GRACE_S
from bridge.service.server import HitchService
from bridge.service.store import HitchStore
from bridge.service.work import WorkControl
from planner.trajectory import TrajectoryPlanner
from tests.helpers import SimService, wait_until
from tests.integration.service_process import free_port

HARROW = {"name": "harrow", "category": "2", "mass_kg": 1200.0, "com_m": [0.0, 0.6, 0.4]}
#: a light tine implement: draft, mixed and float work need an implement selected (work/start refuses them without)
TINE = {"name": "tine", "category": "2", "mass_kg": 150.0, "com_m": [0.0, 0.3, 0.2]}


class FakeInputs:
    """A draft far below any setpoint (noisy: never "stuck") and a fixed ground reference."""

    def __init__(self, ground_z: float, draft_n: float = 1_000.0):
        self.ground, self.value = ground_z, draft_n

    def draft(self, now):
        return self.value + 10.0 * np.sin(37.0 * now), now

    def slip(self, now):
        return None

    def ground_z(self, now):
        return self.ground


class Service(SimService):
    def __init__(self, model, path, inputs=None):
        super().__init__(model, path, prepare=lambda mc: setattr(mc, "work", WorkControl(mc, inputs)))


@pytest.fixture
def svc(model, tmp_path):
    s = Service(model, tmp_path / "hitch.sqlite3")
    yield s
    s.close()


@pytest.mark.parametrize(
    ("payload", "field", "allowed"),
    [
        ({"blend": 1.5}, "blend", "[0, 1]"),
        ({"draft_setpoint_n": 0.0}, "draft_setpoint_n", "(0, 300000]"),
        ({"sensitivity": 5}, "sensitivity", "[0.1, 2]"),
        ({"depth_max_m": 0.9}, "depth_max_m", "[0, 0.6]"),
        ({"depth_min_m": 0.3, "depth_max_m": 0.2}, "depth_min_m", "[0, 0.6]"),
        ({"slip_limit": 0.7}, "slip_limit", "(0, 0.5]"),
    ],
)
def test_bad_work_settings_name_the_field_and_its_range(svc, payload, field, allowed):
    ok, r = svc.call("work/settings", payload)
    assert not ok and r["error"] == "bad_request", r
    assert field in r["message"] and allowed in r["message"], r
    assert svc.store.get_work_settings("default") is None  # nothing stored


def test_work_settings_round_trip_persisted_per_implement(svc, tmp_path):
    r = svc.ok("work/settings")
    assert r["implement"] == "default" and r["settings"]["mode"] == "position" and not r["status"]["running"]
    svc.ok("work/settings", {"mode": "draft", "draft_setpoint_n": 18_000.0, "depth_min_m": 0.1, "slip_limit": 0.2})
    ok, r = svc.call("work/settings", {"mode": "plough"})
    assert not ok and "mode" in r["message"]
    r = svc.ok("work/settings")
    assert r["settings"] == {
        "mode": "draft",
        "draft_setpoint_n": 18_000.0,
        "blend": 0.5,
        "sensitivity": 1.0,
        "depth_min_m": 0.1,
        "depth_max_m": 0.35,
        "slip_limit": 0.2,
    }
    assert r["status"]["settings"]["mode"] == "draft"  # the controller's work control has them too
    svc.ok("work/settings", {"slip_limit": None})  # null: slip limiting off, the rest kept
    assert svc.ok("work/settings")["settings"]["slip_limit"] is None
    # null elsewhere keeps the setting, as docs/api.md offers it ("mode": null was refused "got None")
    r = svc.ok("work/settings", {"mode": None, "blend": None, "sensitivity": 1.2})
    assert r["settings"]["mode"] == "draft" and r["settings"]["blend"] == 0.5 and r["settings"]["sensitivity"] == 1.2
    svc.ok("work/settings", {"sensitivity": 1.0})
    # another implement has its own settings (the defaults until set); back to the first: its own again
    svc.ok("implements/define", HARROW)
    svc.ok("implements/define", {**HARROW, "name": "plough"})
    svc.ok("implements/select", {"name": "harrow"})
    r = svc.ok("work/settings")
    assert r["implement"] == "harrow" and r["settings"]["mode"] == "position"
    svc.ok("work/settings", {"mode": "mixed", "blend": 0.3})
    svc.ok("implements/select", {"name": "plough"})
    assert svc.ok("work/settings")["settings"]["mode"] == "position"
    svc.ok("implements/select", {"name": "harrow"})
    assert svc.ok("work/settings")["settings"]["blend"] == 0.3
    # persisted: a reopened store has both
    svc.store.close()
    with HitchStore(tmp_path / "hitch.sqlite3") as again:
        assert again.get_work_settings("harrow")["blend"] == 0.3
        assert again.get_work_settings("default")["mode"] == "draft"
    svc.store = HitchStore(tmp_path / "hitch.sqlite3")


def test_work_keys_are_operator_keys(svc):
    from bridge.service.security import MOTION_KEYS, WRITE_KEYS

    assert {"work/start", "work/stop", "work/resume"} <= set(MOTION_KEYS) and "work/settings" in WRITE_KEYS


def _tine_in_draft(model, tmp_path) -> Service:
    """A service with the tine selected, in draft control at 20 kN, the ground 0.5 m above the lowest z."""
    lo_z = float(TrajectoryPlanner(model).lo[1])
    s = Service(model, tmp_path / "h.sqlite3", FakeInputs(ground_z=lo_z + 0.5))
    try:
        s.ok("implements/define", TINE)
        s.ok("implements/select", {"name": "tine"})
        s.ok("work/settings", {"mode": "draft", "draft_setpoint_n": 20_000.0, "depth_max_m": 0.3})
    except BaseException:
        s.close()
        raise
    return s


def test_work_and_another_track_stream_never_take_each_other_over_silently(model, tmp_path):
    """A levelling operator's track/start ended a running work session (draft control) without a word, and
    work/start ended a live levelling stream: each is now refused busy naming the live session; work/start
    again still replaces work's own session (the test above)."""
    s = _tine_in_draft(model, tmp_path)
    try:
        work = s.ok("work/start", {"deadline_ms": 10_000})["session"]
        s.run(0.3)
        ok, r = s.call("track/start", {"dof": ["roll"], "ttl_ms": 500})
        assert not ok and r["error"] == "busy", r
        assert (
            f"track session {work} (frame tractor, dof z) is live (work control's: work/stop ends it)" in r["message"]
        ), r
        s.run(0.3)
        assert s.states[-1]["work"]["running"] and s.states[-1]["track"]["session"] == work
        s.ok("work/stop")
        s.run(1.5)
        assert s.states[-1]["motion"] is None
        level = s.ok("track/start", {"dof": ["roll"], "ttl_ms": 500})["session"]
        ok, r = s.call("work/start", {"deadline_ms": 10_000})
        assert not ok and r["error"] == "busy" and f"track session {level} " in r["message"], r
        # work/start has no replace: it is told to end the stream first (a new user's trial: it was told replace)
        assert "replace" not in r["message"] and "end it first (track/stop" in r["message"], r
        assert not s.states[-1]["work"]["running"]
    finally:
        s.close()


def test_a_work_start_or_resume_that_waited_past_its_deadline_or_a_later_stop_is_refused(model, tmp_path):
    """``work/start`` and ``work/resume`` start motion: they came without a deadline and ran whenever a worker
    took them (fails on the old code: a 6 s old start began a session)."""
    s = _tine_in_draft(model, tmp_path)
    try:
        for key in ("work/start", "work/resume"):
            ok, r = s.call(key, {}, received=time.monotonic() - 6.0)
            assert not ok and r["error"] == "busy" and "deadline" in r["message"], (key, r)
        s.run(0.5)
        assert not s.states[-1]["work"]["running"] and s.states[-1]["motion"] is None
        queued = time.monotonic()  # a start waiting in a queue when the operator stops
        assert s.call("stop", {})[0]
        ok, r = s.call("work/start", {}, received=queued)
        assert not ok and r["error"] == "busy" and "stop" in r["message"], r
        s.run(0.5)
        assert not s.states[-1]["work"]["running"]
        time.sleep(STOP_GRACE_S + 0.02)  # within it, a request may have been sent before the stop: refused
        r = started = s.ok("work/start", {"deadline_ms": 10_000})  # sent after the stop: starts
        assert r["work"]["running"]
        ok, r = s.call("work/resume", {}, received=time.monotonic() - 6.0)  # also before the stop
        assert not ok and r == {
            "error": "busy",
            "message": "work/resume: resume cancelled: a stop was sent after this request arrived; not run later",
        }
        assert s.call("work/resume", {})[0]  # in time: taken (no fallback to clear: the configured mode runs)
        # a second work/start replaces the session: the first one's end is announced (it ended without a word:
        # a new user's report)
        first = started["session"]
        again = s.ok("work/start", {"deadline_ms": 10_000})
        s.run(0.2)
        ends = [e for e in s.events if e["event"] == "work_finished" and e["session"] == first]
        assert ends and ends[0]["reason"] == f"replaced by work/start (session {again['session']})", s.events[-6:]
        # a goto (a preset, a maneuver) during work names what ends it: work/stop, not the track/stop the
        # operator never sent (a field trial)
        ok, r = s.call("goto", {"goal": {"z": 0.1}, "deadline_ms": 10_000})
        assert not ok and r["error"] == "busy", r
        assert f"work session {again['session']} is active" in r["message"] and "hitch work stop" in r["message"]
        assert "track/stop" not in r["message"], r
    finally:
        s.close()


def test_a_draft_demand_beyond_the_depth_and_workspace_limits_is_clipped_and_named(model, tmp_path):
    """A draft far below the setpoint drives the regulator to its deepest allowed z: clipped at the depth
    limit first (``work:depth_max``); with a depth limit below the workspace the follower clips it at the
    workspace face and names it, and the hitch stays inside the workspace."""
    lo_z = float(TrajectoryPlanner(model).lo[1])
    s = Service(model, tmp_path / "h.sqlite3", FakeInputs(ground_z=lo_z + 0.5))
    try:
        s.ok("implements/define", TINE)
        s.ok("implements/select", {"name": "tine"})
        s.ok("work/settings", {"mode": "draft", "draft_setpoint_n": 20_000.0, "depth_min_m": 0.1, "depth_max_m": 0.3})
        r = s.ok("work/start", {"z": lo_z + 0.3})
        assert r["work"]["running"] and r["session"] >= 1
        s.run(3.0)
        w = s.states[-1]["work"]
        assert w["active"] == "draft" and w["fallback"] is None
        assert w["z_setpoint"] == pytest.approx(lo_z + 0.5 - 0.3, abs=1e-9)  # ground - depth_max
        assert w["limited"] == {"depth": "work:depth_max"}
        assert abs(s.states[-1]["pose"]["z"] - (lo_z + 0.2)) < 5e-3
        # a depth limit that lies below the workspace: the demand stops at the face (no windup beyond it), the
        # face is named and the depth reported is the one the hitch can reach (not the depth limit's)
        s.ok("work/settings", {"depth_max_m": 0.6})
        s.run(4.0)
        w = s.states[-1]["work"]
        assert w["z_setpoint"] == pytest.approx(lo_z, abs=1e-9)
        assert w["depth_m"] == pytest.approx(0.5, abs=1e-9)
        assert w["limited"] == {"z": "workspace:z:min"}
        assert "z" in s.states[-1]["limited"]  # the state's "control limited" names it too
        assert s.states[-1]["pose"]["z"] >= lo_z - 2e-3
        assert not any(e["event"] == "work_fallback" for e in s.events)
        s.ok("work/stop")
        s.run(1.0)
        assert not s.states[-1]["work"]["running"] and s.states[-1]["motion"] is None
        assert any(e["event"] == "work_finished" for e in s.events)
        ok, r = s.call("work/stop")
        assert not ok and r["error"] == "not_found"
    finally:
        s.close()


def test_work_start_refuses_a_setpoint_outside_the_workspace_naming_its_range(model, tmp_path):
    """The old service accepted z = 1.4 m (the schema's -1..1.5 m), and the session then died ~0.3 s later
    on its own rejected setpoints ('stale: no setpoint within 300 ms')."""
    lo_z, hi_z = (float(v) for v in (TrajectoryPlanner(model).lo[1], TrajectoryPlanner(model).hi[1]))
    s = Service(model, tmp_path / "h.sqlite3", FakeInputs(ground_z=0.3))
    tp = TrajectoryPlanner(model)  # the service's config carries its workspace (machine.service_info)
    s.api.info["limits"] = {"workspace": {k: list(tp.workspace[k]) for k in ("x", "z", "roll", "pitch")}}
    try:
        for z, side in ((1.4, "above"), (-0.9, "below")):
            ok, r = s.call("work/start", {"z": z})
            assert not ok and r["error"] == "unreachable", r
            assert f"z = {z:g} m is {side} the workspace (z from {lo_z:.4g} to {hi_z:.4g} m" in r["message"], r
        ok, r = s.call("work/start", {"z": 250})
        assert not ok and "did you mean mm?" in r["message"], r
        assert s.states == [] or s.states[-1]["motion"] is None  # nothing started
        assert s.ok("work/start", {"z": lo_z + 0.1})["work"]["running"]  # inside: accepted
    finally:
        s.close()


def test_without_a_draft_draft_mode_falls_back_once_and_resume_engages_again(model, tmp_path):
    inputs = FakeInputs(ground_z=0.3)
    s = Service(model, tmp_path / "h.sqlite3", inputs)
    try:
        s.ok("implements/define", TINE)
        s.ok("implements/select", {"name": "tine"})
        s.ok("work/settings", {"mode": "draft"})
        inputs.draft = lambda now: (None, now)  # type: ignore[method-assign]
        s.ok("work/start", {"z": 0.1})
        s.run(1.0)
        fb = [e for e in s.events if e["event"] == "work_fallback"]
        assert len(fb) == 1 and "stale: no reading" in fb[0]["reason"], fb
        w = s.states[-1]["work"]
        assert w["active"] == "position" and "no reading" in w["fallback"]
        assert abs(s.states[-1]["pose"]["z"] - 0.1) < 5e-3  # position control continues
        inputs.draft = lambda now: (20_000.0 + 10.0 * np.sin(37.0 * now), now)  # type: ignore[method-assign]
        s.ok("work/resume")
        s.run(0.5)
        w = s.states[-1]["work"]
        assert w["active"] == "draft" and w["fallback"] is None
        assert len([e for e in s.events if e["event"] == "work_fallback"]) == 1
    finally:
        s.close()


def test_a_plain_track_setpoint_for_the_work_session_is_refused_and_counted(model, tmp_path):
    """A ``track/setpoint`` stream naming the work session's id must not compete with work control: each
    one is refused (``busy``) and counted, and the hitch stays at the work controller's z (on the old
    code they were accepted and the hitch followed the stream to 0.2 m)."""
    s = Service(model, tmp_path / "h.sqlite3", FakeInputs(ground_z=0.3))
    try:
        s.ok("work/settings", {"mode": "position"})
        session = s.ok("work/start", {"z": 0.05})["session"]
        s.run(1.5)
        for seq in range(1, 41):
            ok, r = s.call("track/setpoint", {"session": session, "seq": seq, "pose": {"z": 0.2}})
            assert not ok and r["error"] == "busy" and "work session" in r["message"], r
            s.run(0.02)
        s.run(1.5)
        st = s.states[-1]
        assert st["work"]["running"] and st["work"]["setpoints_refused"] == 40
        assert st["track"]["session"] == session and st["track"]["rejected"] == 40
        assert "work session" in st["track"]["last_rejection"]
        assert abs(st["pose"]["z"] - 0.05) < 5e-3  # work control's z, not the stream's
        # another session's id is still "not live", as before
        ok, r = s.call("track/setpoint", {"session": session + 1, "seq": 1, "pose": {"z": 0.2}})
        assert not ok and r["error"] == "not_found"
        s.ok("work/stop")
    finally:
        s.close()


def test_track_stop_with_a_last_seq_brakes_a_work_session_at_once(model, tmp_path):
    """Work control feeds its session; no client sequence exists to wait for. A ``track/stop`` naming a
    ``last_seq`` brakes at once (review finding: it waited the whole ttl while work control went on)."""
    s = Service(model, tmp_path / "h.sqlite3", FakeInputs(ground_z=0.3))
    try:
        s.ok("work/settings", {"mode": "position"})
        session = s.ok("work/start", {"z": 0.05})["session"]
        s.run(1.0)
        reply = s.ok("track/stop", {"session": session, "last_seq": 10**6})
        assert reply["stopping"] and "after_seq" not in reply, reply
        s.run(0.04)
        assert s.states[-1]["track"] is None or s.states[-1]["track"]["ending"]
    finally:
        s.close()


# ---------------------------------------------------------------------- the core in its own process
FLAT_FIELD = """
schema_version = 1
name = "patches"
scenario = "flat"
[implement]
kind = "chisel_plow_straight_point"
width = 9.0
working_depth_m = 0.2
[soil]
variation = 0.3
patch_length_m = 20.0
blend_m = 2.0
seed = 4
"""


def _start(tmp_path, **kw) -> HitchService:
    cfg = ServiceConfig(listen=[f"tcp/127.0.0.1:{free_port()}"], data_dir=tmp_path, planning_processes=0, **kw)
    svc = HitchService(cfg).start()
    assert svc.core is not None  # the default: the core has its own process
    assert wait_until(lambda: ((svc.latest_state or {}).get("ecu") or {}).get("online")), "no state from the core"
    return svc


def _call(svc, key, payload=None):
    ok, r = svc.api.handle(key, json.dumps(payload or {}))
    assert ok, (key, r)
    return r


def _collect(svc, seconds: float) -> list[dict]:
    got: list[dict] = []
    svc.add_listener("state", lambda m: got.append(m["work"]) if m.get("work") else None)
    time.sleep(seconds)
    return [w for w in got if w.get("running")]


@pytest.mark.slow
def test_draft_control_over_a_sim_field_holds_the_draft_closer_than_position_control(tmp_path):
    field = tmp_path / "patches.toml"
    field.write_text(FLAT_FIELD)
    svc = _start(tmp_path, sim_field=str(field))
    events: list[dict] = []
    svc.add_listener("event", events.append)
    try:
        _call(svc, "work/settings", {"mode": "position"})
        _call(svc, "work/start", {"z": 0.0})
        pos = _collect(svc, 8.0)
        drafts_pos = np.array([w["draft_n"] for w in pos[100:] if w["draft_n"] is not None])
        assert drafts_pos.size > 100 and drafts_pos.mean() > 5_000.0, drafts_pos.size  # the draft pins are on the bus
        setpoint = float(0.8 * drafts_pos.mean())
        _call(svc, "work/settings", {"mode": "draft", "draft_setpoint_n": setpoint, "depth_min_m": 0.05})
        drf = _collect(svc, 8.0)
        drafts = np.array([w["draft_n"] for w in drf[150:] if w["draft_n"] is not None])
        assert {w["active"] for w in drf[150:]} == {"draft"}
        dev_pos = float(np.sqrt(np.mean((drafts_pos - setpoint) ** 2)))
        dev_drf = float(np.sqrt(np.mean((drafts - setpoint) ** 2)))
        assert dev_drf < 0.6 * dev_pos, (dev_drf, dev_pos)
        assert not [e for e in events if e.get("event") == "work_fallback"]
        _call(svc, "work/stop")
    finally:
        svc.close()


@pytest.mark.slow
def test_without_a_sim_field_draft_mode_falls_back_at_once_with_one_event(tmp_path):
    svc = _start(tmp_path)
    events: list[dict] = []
    svc.add_listener("event", events.append)
    try:
        _call(svc, "implements/define", TINE)
        _call(svc, "implements/select", {"name": "tine"})
        _call(svc, "work/settings", {"mode": "draft"})
        r = _call(svc, "work/start", {"z": 0.05})
        assert r["session"] >= 1
        assert wait_until(lambda: any(e.get("event") == "work_fallback" for e in events), 10.0)
        time.sleep(1.0)
        fb = [e for e in events if e.get("event") == "work_fallback"]
        assert len(fb) == 1 and fb[0]["reason"] == "draft signal stale: no reading", fb
        w = svc.latest_state["work"]
        assert w["running"] and w["active"] == "position" and w["fallback"] == "draft signal stale: no reading"
        assert wait_until(lambda: abs(svc.latest_state["pose"]["z"] - 0.05) < 5e-3, 10.0)  # position control goes on
        status = _call(svc, "work/settings")["status"]
        assert status["slip"] is None and "not on the bus" in status["slip_note"]
        _call(svc, "work/stop")
        assert wait_until(lambda: not svc.latest_state["work"]["running"], 10.0)
    finally:
        svc.close()


def test_the_cli_sends_the_draft_setpoint_in_newtons_and_prints_the_work_block_with_units():
    from bridge.cli.main import build_parser
    from bridge.cli.work import format_status, settings_body

    args = build_parser().parse_args(
        ["work", "settings", "--mode", "draft", "--draft-setpoint-kn", "18.5", "--depth-max", "0.3", "--no-slip-limit"]
    )
    assert settings_body(args) == {
        "mode": "draft",
        "draft_setpoint_n": 18_500.0,
        "depth_max_m": 0.3,
        "slip_limit": None,
    }
    from bridge.cli.errors import CLIError

    with pytest.raises(CLIError, match="not allowed with"):  # both: which is meant is not known (off won silently)
        build_parser().parse_args(["work", "settings", "--slip-limit", "0.1", "--no-slip-limit"])
    text = format_status(
        {"running": True, "session": 3, "mode": "draft", "active": "position", "fallback": "stale: no reading",
         "draft_n": 21_000.0, "draft_setpoint_n": 18_500.0, "depth_m": 0.21, "z_setpoint": -0.01, "slip": None,
         "slip_action": "none", "slip_note": "slip unavailable", "limited": {"depth": "work:depth_max"}}
    )  # fmt: skip
    assert "draft 21.00 kN (setpoint 18.50 kN)" in text and "depth 0.210 m" in text and "fallback" in text
    assert "slip unknown" in text and "depth: work:depth_max" in text
    for action in ("start", "stop", "resume", "status"):
        assert build_parser().parse_args(["work", action]).action == action


@pytest.mark.slow
def test_losing_the_fields_draft_in_the_running_twin_falls_back_once_and_position_control_goes_on(tmp_path):
    """The running service (core in the service's threads, so the test reaches the twin's ECU node): a
    draft session over a sim field, then the field's draft pins are lost (the ECU node's draft source
    sends "not available" from now on, as ``FieldDraft(lost_at_s=…)`` in the field loop): exactly one
    ``work_fallback`` event, the same track session goes on in position control to the operator's z."""
    field = tmp_path / "patches.toml"
    field.write_text(FLAT_FIELD)
    cfg = ServiceConfig(
        listen=[f"tcp/127.0.0.1:{free_port()}"],
        data_dir=tmp_path,
        planning_processes=0,
        control_core="thread",
        sim_field=str(field),
    )
    svc = HitchService(cfg).start()
    events: list[dict] = []
    svc.add_listener("event", events.append)
    try:
        assert svc.core is None and svc.parts is not None and svc.parts.ecu_node is not None
        assert wait_until(lambda: ((svc.latest_state or {}).get("ecu") or {}).get("online")), "no state"
        _call(svc, "implements/define", TINE)
        _call(svc, "implements/select", {"name": "tine"})
        _call(svc, "work/settings", {"mode": "draft", "draft_setpoint_n": 15_000.0, "depth_min_m": 0.05})
        session = _call(svc, "work/start", {"z": 0.0})["session"]
        assert wait_until(lambda: (svc.latest_state["work"] or {}).get("draft_n") is not None, 10.0), (
            "no draft on the bus"
        )
        time.sleep(2.0)
        w = svc.latest_state["work"]
        assert w["running"] and w["active"] == "draft" and w["fallback"] is None, w
        assert not [e for e in events if e.get("event") == "work_fallback"]
        svc.parts.ecu_node.draft_source.lost_at_s = 0.0  # the pins are lost: RearDraft "not available"
        assert wait_until(lambda: any(e.get("event") == "work_fallback" for e in events), 10.0), "no fallback"
        assert wait_until(lambda: abs(svc.latest_state["pose"]["z"]) < 5e-3, 15.0), svc.latest_state["pose"]
        time.sleep(1.0)
        fb = [e for e in events if e.get("event") == "work_fallback"]
        assert len(fb) == 1 and fb[0]["reason"] == "draft signal stale: no reading", fb
        st = svc.latest_state
        assert st["work"]["running"] and st["work"]["active"] == "position" and st["work"]["session"] == session
        assert st["track"] is not None and st["track"]["session"] == session  # the same session, no brake
        assert not [e for e in events if e.get("event") in ("work_finished", "fault")]
        _call(svc, "work/stop")
        assert wait_until(lambda: not svc.latest_state["work"]["running"], 10.0)
    finally:
        svc.close()


def test_the_live_draft_demand_never_outruns_the_hitch(model, tmp_path):
    """The service's work session bounds the draft demand's rate by what the follower allows a z-only
    session (``draft_rate_limit``), as the simulated field loop does: no step of the z setpoint between
    two states is faster (before: the regulator's proportional step jumped at the start)."""
    from bridge.service.work import draft_rate_limit

    lo_z = float(TrajectoryPlanner(model).lo[1])
    s = Service(model, tmp_path / "h.sqlite3", FakeInputs(ground_z=lo_z + 0.5))
    try:
        s.ok("implements/define", TINE)
        s.ok("implements/select", {"name": "tine"})
        s.ok("work/settings", {"mode": "draft", "draft_setpoint_n": 20_000.0, "depth_min_m": 0.1, "depth_max_m": 0.45})
        z0 = lo_z + 0.35
        s.ok("work/start", {"z": z0})
        s.run(2.0)
        pts = [(st["clock"], st["work"]["z_setpoint"]) for st in s.states if st["work"]["z_setpoint"] is not None]
        pts = [(pts[0][0] - 0.02, z0), *pts]  # the operator's z just before the session's first cycle
        assert len(pts) > 20 and min(z for _, z in pts) < z0 - 0.05  # it went deeper
        limit = draft_rate_limit(TrajectoryPlanner(model), [0.0, z0, 0.0, 0.0])
        fastest = max(abs(z1 - z_0) / (t1 - t0) for (t0, z_0), (t1, z1) in itertools.pairwise(pts) if t1 > t0)
        assert fastest <= limit * 1.02, (fastest, limit)
    finally:
        s.close()


def test_a_soil_engaging_work_mode_needs_an_implement(svc):
    """A field trial: draft work started with no implement selected ("selected: none") and drove the hitch down
    under draft control. Draft, mixed and float work need an implement; position mode works without one."""
    svc.ok("work/settings", {"mode": "draft", "draft_setpoint_n": 20_000.0})
    ok, r = svc.call("work/start", {"z": 0.1})
    assert not ok and r["error"] == "not_found", r
    assert "draft mode needs the implement in the soil: no implement is selected" in r["message"], r
    assert "hitch implement select NAME" in r["message"]
    svc.ok("work/settings", {"mode": "position"})
    assert svc.ok("work/start", {"z": 0.1})["work"]["running"]
    svc.ok("work/stop")


def _run_forwarding(s, seconds: float) -> None:
    """``s.run`` with the controller's events handed to the implements logic as the service's event listener does
    (``HitchService.add_listener("event", implements.on_event)``)."""
    seen = len(s.events)

    def each() -> None:
        nonlocal seen
        new, seen = s.events[seen:], len(s.events)
        for e in new:
            s.api.implements.on_event(e)

    s.run(seconds, each)


def _at_work_with_a_headland(s) -> None:
    s.ok("implements/define", {**TINE, "headland": {"x": 0.0, "z": 0.25, "roll": 0.0, "pitch": 0.0}})
    s.ok("implements/select", {"name": "tine"})
    s.ok("work/settings", {"mode": "position"})
    s.ok("work/start", {"z": 0.1})
    _run_forwarding(s, 3.0)
    assert abs(s.states[-1]["pose"]["z"] - 0.1) < 3e-3


def test_a_quick_raise_at_work_pauses_work_and_the_return_starts_it_again(svc):
    """Headland management as operators know it from commercial hitch control: at the headland the raise
    switch lifts the implement out of work control, lowering returns to the work pose and work control takes
    over again. Before, a raise during work was refused (``busy``: "work session … is active")."""
    _at_work_with_a_headland(svc)
    session = svc.states[-1]["work"]["session"]
    r = svc.ok("hitch/raise")
    assert r["accepted"] and r["work_paused"] == {"session": session, "mode": "position", "z_operator": 0.1}, r
    _run_forwarding(svc, r["duration"] + 1.0)
    assert abs(svc.states[-1]["pose"]["z"] - 0.25) < 1e-3 and not svc.states[-1]["work"]["running"]
    paused = [e for e in svc.events if e["event"] == "work_paused"]
    finished = [e for e in svc.events if e["event"] == "work_finished"]
    assert len(paused) == 1 and paused[0]["session"] == session and "hitch/return" in paused[0]["message"]
    assert len(finished) == 1 and finished[0]["reason"] == "quick raise (hitch/raise)", finished
    r = svc.ok("hitch/return")
    assert r["resumes_work"]["session"] == session, r
    _run_forwarding(svc, r["duration"] + 0.5)
    assert wait_until(lambda: any(e["event"] == "work_resumed" for e in svc.events))
    _run_forwarding(svc, 2.0)
    w = svc.states[-1]["work"]
    assert w["running"] and w["session"] != session and w["z_operator"] == pytest.approx(0.1)
    assert abs(svc.states[-1]["pose"]["z"] - 0.1) < 3e-3
    assert svc.api.implements.paused_work is None


def test_paused_work_starts_again_only_when_the_return_arrives_and_work_stop_forgets_it(svc):
    """A stop during the return keeps the pause (the next return starts work once it arrives); ``work/stop`` at
    the headland forgets it: the return then only goes back."""
    _at_work_with_a_headland(svc)
    r = svc.ok("hitch/raise")
    _run_forwarding(svc, r["duration"] + 1.0)
    svc.ok("hitch/return")
    _run_forwarding(svc, 0.3)
    svc.ok("stop")
    _run_forwarding(svc, 2.0)
    assert not svc.states[-1]["work"]["running"] and svc.api.implements.paused_work is not None
    time.sleep(STOP_GRACE_S + 0.02)  # a return just after a stop may have been sent before it: refused
    r = svc.ok("hitch/return")
    _run_forwarding(svc, r["duration"] + 0.5)
    assert wait_until(lambda: any(e["event"] == "work_resumed" for e in svc.events))
    _run_forwarding(svc, 0.5)
    assert svc.states[-1]["work"]["running"]
    r = svc.ok("hitch/raise")
    _run_forwarding(svc, r["duration"] + 1.0)
    cleared = svc.ok("work/stop")
    assert cleared["stopping"] is False and cleared["work_paused_cleared"]["z_operator"] == pytest.approx(0.1)
    ok, r = svc.call("work/stop")
    assert not ok and r["error"] == "not_found", r
    r = svc.ok("hitch/return")
    assert "resumes_work" not in r
    _run_forwarding(svc, r["duration"] + 1.0)
    assert not svc.states[-1]["work"]["running"]
    assert len([e for e in svc.events if e["event"] == "work_resumed"]) == 1


@pytest.mark.slow
def test_the_operator_switch_pauses_work_at_the_headland_and_resumes_it_with_the_core_in_its_own_process(tmp_path):
    """The tractor's raise / lower switch (the twin's CAN switch) during work, the core in its own process."""
    svc = _start(tmp_path)
    events: list[dict] = []
    svc.add_listener("event", events.append)
    try:
        _call(svc, "implements/define", {**TINE, "headland": {"x": 0.0, "z": 0.25, "roll": 0.0, "pitch": 0.0}})
        _call(svc, "implements/select", {"name": "tine"})
        _call(svc, "work/settings", {"mode": "position"})
        first = _call(svc, "work/start", {"z": 0.05})["session"]
        assert wait_until(lambda: abs(svc.latest_state["pose"]["z"] - 0.05) < 3e-3, 10.0)
        _call(svc, "sim/switch", {"position": "raise"})
        assert wait_until(lambda: abs(svc.latest_state["pose"]["z"] - 0.25) < 3e-3, 15.0), svc.latest_state["pose"]
        assert not svc.latest_state["work"]["running"]
        assert [e["session"] for e in events if e.get("event") == "work_paused"] == [first]
        _call(svc, "sim/switch", {"position": "lower"})
        assert wait_until(lambda: any(e.get("event") == "work_resumed" for e in events), 15.0), events[-5:]
        assert wait_until(lambda: svc.latest_state["work"]["running"], 5.0), [str(e) for e in events[-6:]]
        assert wait_until(lambda: abs(svc.latest_state["pose"]["z"] - 0.05) < 3e-3, 10.0)
        w = svc.latest_state["work"]
        assert w["running"] and w["session"] != first and w["z_operator"] == pytest.approx(0.05), w
        assert not [e for e in events if e.get("event") in ("hitch_switch_refused", "work_resume_refused")], events
    finally:
        svc.close()


def test_work_started_again_by_a_return_is_cancelled_by_a_stop_sent_after_the_return_arrived(svc):
    """A reviewer's finding: the work/start that follows an arrived return was stamped when its thread ran, so
    a stop pressed after the return arrived, with the event delivered more than STOP_GRACE_S later, did not
    cancel it: work (motion) began after the stop. It is stamped with the arrival's own time now."""
    _at_work_with_a_headland(svc)
    r = svc.ok("hitch/raise")
    _run_forwarding(svc, r["duration"] + 1.0)
    r = svc.ok("hitch/return")
    seen = len(svc.events)
    svc.run(r["duration"] + 0.5)  # it arrives; its motion_finished not yet handed to the implement logic
    assert any(e["event"] == "motion_finished" and e["motion_id"] == r["motion_id"] for e in svc.events[seen:])
    assert svc.call("stop")[0]  # the operator stops after the arrival
    time.sleep(STOP_GRACE_S + 0.05)  # the event reaches the listener late
    _run_forwarding(svc, 0.0)
    for e in svc.events[seen:]:
        svc.api.implements.on_event(e)
    assert wait_until(lambda: any(e["event"] == "work_resume_refused" for e in svc.events))
    refused = [e for e in svc.events if e["event"] == "work_resume_refused"][0]
    assert "stop" in refused["message"], refused
    _run_forwarding(svc, 1.0)
    assert not svc.states[-1]["work"]["running"] and not svc.states[-1]["moving"]


def test_a_raise_refused_after_it_ended_work_keeps_this_work_pose_for_the_return(svc):
    """A reviewer's finding: the raise ends the work session, then its goto may be refused (a fault, a late
    request); the work pose was then not recorded and the return went to an earlier headland turn's pose."""
    from bridge.service.motion.types import Fault

    _at_work_with_a_headland(svc)
    svc.ok("work/stop")
    _run_forwarding(svc, 1.0)
    svc.ok("goto", {"goal": {"z": 0.02}})  # an earlier work pose, recorded by a raise from it
    _run_forwarding(svc, 3.0)
    r = svc.ok("hitch/raise")
    _run_forwarding(svc, r["duration"] + 0.5)
    time.sleep(STOP_GRACE_S + 0.02)
    svc.ok("work/start", {"z": 0.1})  # a new work session at another depth
    _run_forwarding(svc, 3.0)
    svc.mc._faults.hold(Fault("internal", "a test's fault", True, 0.0))  # noqa: SLF001 — goto refused
    ok, r = svc.call("hitch/raise")
    assert not ok and "has ended" in r["message"], r
    last = svc.store.get_implement("tine").last_work
    assert last is not None and last["z"] == pytest.approx(0.1, abs=5e-3), last


def test_a_motion_event_never_waits_for_an_implement_change_in_progress(tmp_path):
    """A reviewer's finding: the event listener took the implement lock, which a select holds across its call to
    the core; with the core in its own process both run on the one thread that reads the core's replies, so the
    select waited 10 s for a reply that thread could not read. A motion event never takes that lock now."""
    import threading

    from bridge.service.implements import ImplementService
    from bridge.service.schemas import ImplementDefine
    from bridge.service.store import HitchStore

    store = HitchStore(tmp_path / "h.sqlite3")
    handled = threading.Event()

    class Motion:
        def select_implement(self, implement, limits, *, announce=True):
            # the reply reader delivers a motion event while this call waits for its reply
            def deliver():
                svc.on_event({"event": "motion_finished", "motion_id": 7})
                handled.set()

            threading.Thread(target=deliver).start()
            assert handled.wait(2.0), "the event listener waited for the implement lock"
            return {}

        def post_event(self, event):
            pass

    try:
        svc = ImplementService(store, Motion())
        svc.define(ImplementDefine(**TINE))
        svc.select("tine")
        assert handled.is_set()
    finally:
        store.close()


def test_a_return_whose_arrival_is_announced_before_its_reply_still_starts_the_paused_work(tmp_path):
    """A reviewer's finding: the return's motion id was set on the pause after the goto's reply; with the core in
    its own process a return of almost no length can end, and its motion_finished reach the listener, first:
    the work was then never started again."""
    import threading

    from bridge.service.implements import ImplementService
    from bridge.service.schemas import ImplementDefine, QuickMove
    from bridge.service.store import HitchStore

    store = HitchStore(tmp_path / "h.sqlite3")
    started = threading.Event()

    class Accepted:
        def to_json(self):
            return {"accepted": True, "motion_id": 42, "duration": 0.01}

    class Motion:
        def select_implement(self, implement, limits, *, announce=True):
            return {}

        def goto(self, goal, scale, **kw):
            svc.on_event({"event": "motion_finished", "motion_id": 42, "t": time.time()})  # before the reply
            return Accepted()

        def post_event(self, event):
            pass

    def dispatch(key, payload, user=None, *, received=None):
        assert key == "work/start" and json.loads(payload) == {"z": 0.1}
        started.set()
        return True, {"session": 9}

    try:
        svc = ImplementService(store, Motion())
        svc.dispatch = dispatch
        svc.define(ImplementDefine(**TINE))
        svc.select("tine")
        store.update_implement("tine", last_work={"x": 0.0, "z": 0.1, "roll": 0.0, "pitch": 0.0})
        svc.paused_work = {"implement": "tine", "session": 5, "z": 0.1, "mode": "position", "return_motion": None}
        reply = svc.quick_return(QuickMove(), None, None)
        assert reply["resumes_work"]["session"] == 5
        assert started.wait(2.0), "the paused work was never started again"
    finally:
        store.close()


def test_the_work_block_keeps_no_stale_numbers_after_the_session_ended(model, tmp_path):
    """A field trial: ``work start; work stop; raise --wait; work status`` showed the last session's draft (19.69
    kN), depth, z setpoint, fallback and ``limited: vz …`` with the implement out of the soil. After the session
    the live fields are null/empty (``ended`` says how it ended), in the state and in ``work/settings``."""
    lo_z = float(TrajectoryPlanner(model).lo[1])
    inputs = FakeInputs(ground_z=lo_z + 0.5)
    s = Service(model, tmp_path / "h.sqlite3", inputs)
    live = ("active", "fallback", "draft_n", "depth_m", "z_operator", "z_setpoint")
    try:
        s.ok("implements/define", TINE)
        s.ok("implements/select", {"name": "tine"})
        s.ok("work/settings", {"mode": "draft", "draft_setpoint_n": 20_000.0, "depth_max_m": 0.6})
        for draft in (inputs.draft, lambda now: (None, now)):  # regulating at a limit, then a fallback
            inputs.draft = draft  # type: ignore[method-assign]
            s.ok("work/start", {"z": lo_z + 0.1})
            s.run(3.0)
            w = s.states[-1]["work"]
            assert w["running"] and w["z_setpoint"] is not None and w["depth_m"] is not None, w
            assert w["limited"] or w["fallback"], w
            s.ok("work/stop")
            s.run(1.0)
            for w in (s.states[-1]["work"], s.ok("work/settings")["status"]):
                assert not w["running"] and w["session"] is None, w
                assert {k: w[k] for k in live} == dict.fromkeys(live), w
                assert w["limited"] == {} and w["slip_action"] == "none", w
                assert w["ended"], w  # how the last session ended stays readable
    finally:
        s.close()


def test_a_draft_demand_beyond_the_workspace_floor_stops_there_and_leaves_it_at_once(model, tmp_path):
    """A field trial: draft 300 kN with depth 0..0.6 m drove the setpoint to -0.426 m (depth "0.597 m") with the
    hitch at the workspace floor; set to 8 kN the hitch then stayed at the floor for 2.3 s while the wound-up
    setpoint came back. Now the demand never goes below the floor, the floor is named, the depth is the real
    one, and after a lower setpoint the hitch leaves the floor within the regulator's time constant (1/K_I)."""
    from planner.work_control.controller import KI_DRAFT

    lo_z = float(TrajectoryPlanner(model).lo[1])
    ground = lo_z + 0.3  # the depth limit 0.6 lies 0.3 m below the floor
    s = Service(model, tmp_path / "h.sqlite3", FakeInputs(ground_z=ground))
    try:
        s.ok("implements/define", TINE)
        s.ok("implements/select", {"name": "tine"})
        s.ok("work/settings", {"mode": "draft", "draft_setpoint_n": 300_000.0, "depth_min_m": 0.0, "depth_max_m": 0.6})
        s.ok("work/start", {"z": lo_z + 0.2})
        s.run(8.0)
        zs = [st["work"]["z_setpoint"] for st in s.states if st["work"]["z_setpoint"] is not None]
        assert min(zs) >= lo_z - 1e-9, (min(zs), lo_z)
        w = s.states[-1]["work"]
        assert w["z_setpoint"] == pytest.approx(lo_z, abs=1e-9) and w["depth_m"] == pytest.approx(0.3, abs=1e-9), w
        assert w["limited"] == {"z": "workspace:z:min"}, w
        assert abs(s.states[-1]["pose"]["z"] - lo_z) < 2e-3
        n = len(s.states)
        s.ok("work/settings", {"draft_setpoint_n": 500.0})  # the draft (1 kN) now lies above it: shallower
        s.run(1.0 / KI_DRAFT)
        after = s.states[n:]
        assert after[-1]["pose"]["z"] > lo_z + 0.01, after[-1]["pose"]
        assert after[-1]["work"]["z_setpoint"] > lo_z + 0.03 and "z" not in after[-1]["work"]["limited"]
    finally:
        s.close()


def test_a_sim_field_twin_drives_at_the_users_sim_ground_speed_and_config_reports_the_speed_driven():
    """``sim_ground_speed = 1.5`` with ``sim_field = "chisel"``: the twin drove at the scenario's 8 km/h (GNSS
    2.222 m/s) while ``config`` said 1.5. The user's speed now wins (the tractor's wheel speed, the field's
    draft and the GNSS all follow the twin's speed); without it the scenario's speed is driven, and
    ``simulated_ground_speed`` gives the speed the twin drives either way."""
    from types import SimpleNamespace

    from bridge.service import work
    from bridge.service.work import sim_field_tractor

    def twin(**kw):
        cfg = ServiceConfig(sim_field="chisel", **kw)
        ecu = SimpleNamespace(draft_source=None)
        node = sim_field_tractor(cfg, None, lambda t: None, ecu, 0.5)
        return cfg, node, ecu.draft_source

    cfg, node, draft = twin(sim_ground_speed=1.5)
    assert node.sensors.twin.speed.speed_m_s(10.0) == pytest.approx(1.5)
    assert node.sensors.wheel_speed(10.0).speed_m_s == pytest.approx(1.5, rel=1e-3)
    assert draft.run.step(10.0).speed_m_s == pytest.approx(1.5)  # the draft is that of the speed driven
    simulated_ground_speed = work.simulated_ground_speed  # what the config reply should say (machine.service_info)
    assert simulated_ground_speed(cfg) == pytest.approx(1.5)
    cfg, node, draft = twin()  # not given: the scenario's 8 km/h, and the config says so
    assert node.sensors.twin.speed.speed_m_s(10.0) == pytest.approx(8 / 3.6, abs=1e-3)
    assert simulated_ground_speed(cfg) == pytest.approx(8 / 3.6, abs=1e-3)
    assert simulated_ground_speed(ServiceConfig(sim_ground_speed=3.0)) == 3.0  # no field: as configured


def test_the_config_reply_names_the_ground_speed_the_field_twin_drives():
    """machine.service_info said ``sim_ground_speed``'s default 1.5 m/s while a field twin drove its scenario's
    8 km/h (a field trial)."""
    from bridge.service.machine import build_guard, build_model, service_info

    for kw, speed in (({}, 8 / 3.6), ({"sim_ground_speed": 3.0}, 3.0)):
        cfg = ServiceConfig(sim_field="chisel", **kw)
        info = service_info(cfg, build_guard(cfg, build_model(cfg)))
        assert info["can"]["simulated_ground_speed"] == pytest.approx(speed, abs=1e-3), (kw, info["can"])


def test_the_core_process_reads_the_config_with_the_fields_the_user_set():
    """A review: the service handed its config to the core process as a full dump, which marked every field set:
    with the core in its own process (the default) the field twin took sim_ground_speed's default 1.5 m/s for
    the user's and drove at it, not at the field's 8 km/h."""
    from bridge.service.core.client import core_config_json
    from bridge.service.work import simulated_ground_speed

    for kw in (
        {"sim_field": "chisel"},
        {"sim_field": "chisel", "sim_ground_speed": 1.5},
        {"mode": "client", "connect": ["tcp/127.0.0.1:7447"]},
    ):
        cfg = ServiceConfig(**kw)
        copy = ServiceConfig.model_validate_json(core_config_json(cfg))
        assert copy == cfg and copy.model_fields_set == cfg.model_fields_set, kw
        assert simulated_ground_speed(copy) == simulated_ground_speed(cfg), kw


def test_work_finished_says_why_its_track_session_ended(svc):
    """A safety trial: ``work_finished`` said "the track session ended" whether a stop, a fault, a lost link or
    references_lost ended it; the cause was only in ``motion_aborted``. Now it carries the session's own end."""
    svc.ok("work/settings", {"mode": "position"})
    svc.ok("work/start", {"z": 0.1})
    _run_forwarding(svc, 1.0)
    session = svc.states[-1]["work"]["session"]
    svc.ok("stop")
    _run_forwarding(svc, 1.0)
    finished = [e for e in svc.events if e["event"] == "work_finished" and e["session"] == session]
    assert len(finished) == 1, finished
    assert finished[0]["reason"] == "the track session ended: stop requested", finished
