"""Track mode through the service API on the simulated rig (simulated time, real CAN path):
sessions, streamed setpoints followed online, clipping at the workspace with the limit named,
the TTL stop, precedence stop > jog > track > goto, sequence numbers, access control and the
``level`` / ``ground`` frames against their definitions (``docs/tracking.md``).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bridge.service.api import ServiceAPI
from bridge.service.motion.controller import MotionController
from bridge.service.motion.types import MotionError
from bridge.service.schemas import RequestError, parse_request
from bridge.service.security import AccessPolicy
from bridge.service.store import HitchStore
from bridge.sim.move import SimRig
from planner.ik_qp.hitch_ik import IKSolver
from planner.limits.guard import Guard
from planner.trajectory import TrajectoryPlanner

DT = 0.02


class FakeSensors:
    """Tractor readings set by the test (None: no fresh reading)."""

    def __init__(self):
        self.att: tuple[float, float] | None = None
        self.dist: float | None = None

    def attitude(self, now):
        return self.att

    def ground_distance(self, now):
        return self.dist


class Rig:
    def __init__(self, model, tmp_path, policy=None):
        self.rig = SimRig(model)
        self.rig.start()
        self.rig.run_until(0.5)
        self.events: list[dict] = []
        self.states: list[dict] = []
        self.sensors = FakeSensors()
        self.mc = MotionController(
            Guard(TrajectoryPlanner(model)),
            Guard(TrajectoryPlanner(model)),
            self.rig.link,
            lambda: self.rig.now_s,
            on_event=self.events.append,
            on_state=self.states.append,
            spawn=lambda fn: fn(),
            sensors=self.sensors,
        )
        self.store = HitchStore(tmp_path / "hitch.sqlite3")
        self.api = ServiceAPI(self.mc, IKSolver(model), self.store, {"profile": "thesis-t132"}, policy=policy)
        self.planner = self.mc.planner
        self.seq = 0
        self.run(0.1)

    def call(self, key, payload=None, user=None):
        return self.api.handle(key, json.dumps(payload if payload is not None else {}), user)

    def run(self, seconds, each=None):
        end = self.rig.now_s + seconds
        while self.rig.now_s < end - 1e-9:
            if each is not None:
                each(self.rig.now_s)
            self.rig.run_until(self.rig.now_s + DT)
            self.mc.cycle()

    def setpoint(self, session, pose, velocity=None, seq=None, user=None):
        self.seq += 1
        body = {"session": session, "seq": self.seq if seq is None else seq, "pose": pose}
        if velocity is not None:
            body["velocity"] = velocity
        return self.call("track/setpoint", body, user)

    def measured(self):
        return np.array([self.states[-1]["pose"][k] for k in ("x", "z", "roll", "pitch")])

    def start(self, **kw):
        ok, reply = self.call("track/start", {"dof": ["z"], "ttl_ms": 300, **kw})
        assert ok, reply
        return reply["session"]


@pytest.fixture
def r(model, tmp_path):
    rig = Rig(model, tmp_path)
    yield rig
    rig.store.close()
    rig.rig.close()


def _events(r, name):
    return [e for e in r.events if e["event"] == name]


def test_a_streamed_sine_is_followed_on_the_real_can_path(r):
    session = r.start(dof=["z"], ttl_ms=300)
    z0 = r.measured()[1]
    amp, f = 0.02, 0.1
    errors = []

    def stream(t):
        ph = 2 * math.pi * f * (t - t_start)
        r.setpoint(session, {"z": z0 + amp * math.sin(ph)}, {"z": amp * 2 * math.pi * f * math.cos(ph)})

    t_start = r.rig.now_s
    r.run(12.0, each=stream)
    # measured z against the setpoint of ~0.1 s earlier (the hydraulics' lag), last half
    for st in r.states[-250:]:
        t = st["clock"] - t_start - 0.1
        errors.append(st["pose"]["z"] - (z0 + amp * math.sin(2 * math.pi * f * t)))
    assert r.states[-1]["motion"] == "track" and r.states[-1]["track"]["session"] == session
    assert np.sqrt(np.mean(np.square(errors))) < 0.1 * amp, np.sqrt(np.mean(np.square(errors)))


def test_setpoints_outside_the_workspace_are_clipped_named_and_never_left(r):
    session = r.start(dof=["z", "pitch"], ttl_ms=300)
    hi = r.planner.hi
    ok, reply = r.setpoint(session, {"z": 0.6, "pitch": 0.0})
    assert ok and reply["accepted"] and reply["limited"] == {"z": "workspace:z:max"}, reply
    r.run(6.0, each=lambda t: r.setpoint(session, {"z": 0.6, "pitch": 0.0}))
    refs = [s["reference"]["pose"]["z"] for s in r.states if s["reference"] is not None]
    assert max(refs) <= hi[1] + 1e-6
    assert abs(r.measured()[1] - hi[1]) < 3e-3  # it went to the face and stayed there
    assert r.states[-1]["track"]["control_limited"].get("z") == "workspace:z:max"
    assert "z" in r.states[-1]["limited"]


def test_a_stale_stream_brakes_to_rest_and_ends_the_session(r):
    session = r.start(dof=["z"], ttl_ms=200)
    z0 = r.measured()[1]
    r.run(1.0, each=lambda t: r.setpoint(session, {"z": z0 + 0.1}))
    assert r.states[-1]["velocity"]["z"] > 0.01  # moving up
    r.run(3.0)  # the stream stops
    fin = [e for e in _events(r, "motion_finished") if e.get("session") == session]
    assert fin and fin[0]["reason"].startswith("stale"), r.events
    assert r.states[-1]["motion"] is None and abs(r.states[-1]["velocity"]["z"]) < 1e-9
    ok, reply = r.setpoint(session, {"z": z0})
    assert not ok and reply["error"] == "not_found" and "not live" in reply["message"]
    # why (a new user's report: "session 22 is not live (no session is live)")
    assert f"session {session} is not live (it ended: stale: no setpoint within 200 ms" in reply["message"], reply
    z_end = r.measured()[1]
    r.run(1.0)
    assert abs(r.measured()[1] - z_end) < 1e-3  # nothing resumes


def _spy_guard_and_sends(r, refuse_at_call=None):
    """Log ("send", cycle) for each reference the link takes and ("guard", cycle) for each track
    look-ahead; the guard's ``refuse_at_call``-th look-ahead (1-based) is refused."""
    from planner.limits.guard import GuardDecision

    log: list[tuple[str, int]] = []
    guard, link = r.mc.guard, r.mc.link
    check, send = guard.check_jog, link.send_reference

    def check_jog(state, rates, **kw):
        log.append(("guard", r.mc._cycle_n))
        allowed, decision = check(state, rates, **kw)
        if refuse_at_call is not None and sum(1 for k, _ in log if k == "guard") == refuse_at_call:
            return allowed * 0.0, GuardDecision("refused")
        return allowed, decision

    def send_reference(ref, now):
        log.append(("send", r.mc._cycle_n))
        return send(ref, now)

    guard.check_jog, link.send_reference = check_jog, send_reference
    return log


def test_the_track_guard_looks_ahead_after_the_reference_is_sent(r):
    """A streamed setpoint must not wait for the guard's look-ahead (about 1 ms every fifth cycle) on
    its way to the bus: in every cycle with a look-ahead the reference went out first, except before
    the session's first step (on the old code the guard ran first in every such cycle)."""
    session = r.start(dof=["z"])
    z0 = r.measured()[1]
    log = _spy_guard_and_sends(r)
    r.run(0.6, each=lambda t: r.setpoint(session, {"z": z0 + 0.05}))
    guarded = sorted({c for k, c in log if k == "guard"})
    assert len(guarded) >= 5
    first = guarded[0]
    # every fifth step: the first before it, the others at the end of the cycle before the step they serve
    assert [c + 1 - first for c in guarded[1:]] == [5 * i for i in range(1, len(guarded))]
    for c in guarded[1:]:
        in_cycle = [k for k, cc in log if cc == c]
        assert in_cycle == ["send", "guard"], (c, in_cycle)
    assert [k for k, cc in log if cc == first] == ["guard", "send"]  # before the first step: first


def test_a_track_guard_refusal_brakes_from_the_next_step_and_ends_the_session(r):
    session = r.start(dof=["z"])
    z0 = r.measured()[1]
    log = _spy_guard_and_sends(r, refuse_at_call=3)
    speeds: list[float] = []

    def stream(t):
        r.setpoint(session, {"z": z0 + 0.1})
        speeds.append(r.mc._active.follower.state.velocity[1] if r.mc._active is not None else 0.0)

    r.run(3.0, each=stream)
    fin = [e for e in _events(r, "motion_finished") if e.get("session") == session]
    assert fin and fin[0]["reason"] == "guard: motion refused ahead", r.events
    refused_cycle = [c for k, c in log if k == "guard"][2]
    assert not any(k == "guard" for k, c in log if c > refused_cycle)  # braking: no more look-aheads
    assert abs(r.states[-1]["velocity"]["z"]) < 1e-9 and r.states[-1]["motion"] is None


def test_track_stop_ends_smoothly(r):
    session = r.start(dof=["z"])
    z0 = r.measured()[1]
    r.run(1.0, each=lambda t: r.setpoint(session, {"z": z0 + 0.1}))
    ok, reply = r.call("track/stop", {"session": session})
    assert ok and reply["stopping"], reply
    r.run(2.0)
    fin = [e for e in _events(r, "motion_finished") if e.get("session") == session]
    assert fin and fin[0]["reason"] == "track/stop"
    vz = [s["velocity"]["z"] for s in r.states[-120:]]
    # no step: within what z alone may accelerate (the tightest actuator through its column, where it stopped)
    from planner.trajectory.ideal_follower import dof_limits

    z_alone = dof_limits(r.planner, "z", np.clip(r.measured(), r.planner.lo, r.planner.hi)).acceleration
    assert max(np.abs(np.diff(vz))) < z_alone * DT * 1.01


def test_a_stop_that_overtakes_the_last_setpoint_waits_for_it(r):
    """A streamed setpoint (a put) and track/stop (a query) travel different paths: the stop may come
    first. With ``last_seq`` the setpoint sent before the stop is taken, then the follower brakes (on
    the old code it was refused: "the session is stopping"; CI: 100 of 101 taken)."""
    session = r.start(dof=["z"])
    z0 = r.measured()[1]
    r.run(0.2, each=lambda t: r.setpoint(session, {"z": z0 + 0.02}))
    last = r.seq + 1
    ok, reply = r.call("track/stop", {"session": session, "last_seq": last})
    assert ok and reply["stopping"] and reply["after_seq"] == last, reply
    r.run(DT)  # the stop waits: nothing brakes yet
    assert not r.states[-1]["track"]["ending"]
    ok, reply = r.setpoint(session, {"z": z0 + 0.02}, seq=last)  # the overtaken setpoint arrives
    assert ok and reply["accepted"], reply
    r.run(DT)
    tr = r.states[-1]["track"]
    assert tr["ending"] and tr["rejected"] == 0 and tr["setpoints"] == last, tr
    ok, reply = r.setpoint(session, {"z": z0}, seq=last + 1)  # after it: the session is stopping
    assert not ok and "stopping" in reply["message"], reply
    r.run(2.0)
    fin = [e for e in _events(r, "motion_finished") if e.get("session") == session]
    assert fin and fin[0]["reason"] == "track/stop"


def test_a_stop_whose_last_setpoint_was_lost_brakes_after_one_ttl(r):
    session = r.start(dof=["z"], ttl_ms=300)
    z0 = r.measured()[1]
    r.run(0.2, each=lambda t: r.setpoint(session, {"z": z0 + 0.02}))
    ok, reply = r.call("track/stop", {"session": session, "last_seq": r.seq + 5})  # never arrives
    assert ok and reply["after_seq"] == r.seq + 5, reply
    t_stop = r.rig.now_s
    ending_at = None

    def watch(t):
        nonlocal ending_at
        if ending_at is None and r.states[-1]["track"] and r.states[-1]["track"]["ending"]:
            ending_at = t

    r.run(1.0, each=watch)
    assert ending_at is not None and 0.3 - 1e-9 <= ending_at - t_stop <= 0.3 + 2 * DT + 1e-9, ending_at - t_stop
    fin = [e for e in _events(r, "motion_finished") if e.get("session") == session]
    assert fin and fin[0]["reason"] == "track/stop"  # not "stale": the stop asked for it


@pytest.mark.parametrize("last_seq", [None, "seen"])
def test_a_stop_with_nothing_on_the_way_brakes_at_once(r, last_seq):
    session = r.start(dof=["z"])
    z0 = r.measured()[1]
    r.run(0.2, each=lambda t: r.setpoint(session, {"z": z0 + 0.02}))
    body = {"session": session} if last_seq is None else {"session": session, "last_seq": r.seq}
    ok, reply = r.call("track/stop", body)
    assert ok and "after_seq" not in reply, reply
    r.run(DT)
    assert r.states[-1]["track"]["ending"]


def test_track_stop_last_seq_is_checked():
    with pytest.raises(RequestError, match="last_seq"):
        parse_request("track/stop", json.dumps({"last_seq": -1}))


def test_precedence_stop_over_jog_over_track_over_goto(r):
    session = r.start(dof=["z"])
    z0 = r.measured()[1]
    r.run(0.3, each=lambda t: r.setpoint(session, {"z": z0 + 0.05}))
    ok, reply = r.call("goto", {"goal": {"z": 0.1}})
    assert not ok and reply["error"] == "busy" and "track" in reply["message"], reply
    ok, reply = r.call("jog", {"vz": -0.01, "ttl_ms": 200})
    assert ok, reply
    assert any(e.get("reason") == "replaced by jog" for e in _events(r, "motion_aborted"))
    ok, reply = r.call("track/start", {"dof": ["z"]})
    assert not ok and reply["error"] == "busy" and "jog" in reply["message"], reply
    r.run(1.0)  # jog TTL out, braking
    ok, reply = r.call("goto", {"goal": {"z": 0.2}})
    assert ok, reply
    session2 = r.start(dof=["z"])  # a track session replaces a goto
    assert session2 != session
    assert any(e.get("reason") == "replaced by track" for e in _events(r, "motion_aborted"))
    ok, _ = r.call("stop", {})
    assert ok
    ok, reply = r.setpoint(session2, {"z": 0.2})
    assert not ok and reply["error"] == "not_found"


def test_a_second_track_start_is_refused_while_a_stream_is_live_unless_it_replaces(r):
    """A second client's track/start took the live session over without a word to it (a levelling operator
    lost levelling to a CLI stream, and the two streams cut each other off in turn). Now it is refused busy,
    naming the live session, unless sent with replace; a session whose stream went stale is taken over."""
    session = r.start(dof=["roll"], frame="tractor")
    r.run(0.3, each=lambda t: r.setpoint(session, {"roll": 0.0}))
    ok, reply = r.call("track/start", {"dof": ["z"], "ttl_ms": 300})
    assert not ok and reply["error"] == "busy", reply
    assert reply["message"] == (
        f"track/start: track session {session} (frame tractor, dof roll) is live: track/stop ends it; "
        "track/start with replace: true (hitch track --replace) takes it over"
    ), reply
    assert r.states[-1]["track"]["session"] == session  # untouched
    ok, reply = r.setpoint(session, {"roll": 0.0})
    assert ok and reply["accepted"], reply
    session2 = r.start(dof=["z"], replace=True)
    assert session2 != session
    assert any(e.get("reason") == "replaced by track" for e in _events(r, "motion_aborted"))
    ok, reply = r.setpoint(session, {"roll": 0.0})
    assert not ok and "it ended: replaced by track" in reply["message"], reply
    # a stream gone stale (its client crashed) never blocks a new session
    z0 = r.measured()[1]
    r.run(0.6, each=lambda t: r.setpoint(session2, {"z": z0 + 0.1}))
    r.run(0.32)  # > ttl 300 ms: stale, braking from its speed
    assert r.states[-1]["track"]["session"] == session2 and r.states[-1]["track"]["stale"], r.states[-1]["track"]
    session3 = r.start(dof=["z"])
    assert session3 not in (session, session2)


def test_replace_by_session_number_takes_over_only_that_session(r):
    """A review: the terminal's take-over (the operator confirmed "take over track session N") sent replace: true,
    which takes over whatever is live by then — work control's session, had N ended meanwhile. replace: N takes
    over session N only; another live session is refused busy, untouched."""
    session = r.start(dof=["roll"], frame="tractor")
    r.run(0.3, each=lambda t: r.setpoint(session, {"roll": 0.0}))
    ok, reply = r.call("track/start", {"dof": ["z"], "ttl_ms": 300, "replace": session + 1})  # another number
    assert not ok and reply["error"] == "busy" and f"track session {session}" in reply["message"], reply
    assert r.states[-1]["track"]["session"] == session  # untouched
    ok, reply = r.call("track/start", {"dof": ["z"], "ttl_ms": 300, "replace": session})
    assert ok and reply["session"] != session, reply
    for bad in (0, -3, 1.5, "1"):
        ok, reply = r.call("track/start", {"dof": ["z"], "replace": bad})
        assert not ok and reply["error"] == "bad_request" and "replace" in reply["message"], (bad, reply)


def test_old_and_out_of_order_sequence_numbers_are_ignored_and_counted(r):
    session = r.start(dof=["z"])
    z0 = r.measured()[1]
    assert r.setpoint(session, {"z": z0}, seq=10)[1]["accepted"]
    ok, reply = r.setpoint(session, {"z": z0 + 0.2}, seq=9)
    assert ok and not reply["accepted"] and reply["ignored"] == "seq"
    ok, reply = r.setpoint(session, {"z": z0 + 0.2}, seq=10)
    assert not reply["accepted"]
    r.run(0.1, each=lambda t: None)
    assert r.states[-1]["track"]["ignored_seq"] == 2 and r.states[-1]["track"]["setpoints"] == 1
    assert abs(r.states[-1]["track"]["target"]["z"] - z0) < 1e-12  # the ignored ones did not move the target


def test_bad_setpoints_name_the_field_and_are_counted(r):
    session = r.start(dof=["z"])
    ok, reply = r.setpoint(session, {"x": 0.01})  # x is not tracked
    assert not ok and "x" in reply["message"], reply
    ok, reply = r.call("track/setpoint", {"session": session, "seq": 99, "pose": {"z": "high"}})
    assert not ok and "pose.z" in reply["message"], reply
    r.run(0.05)
    # both count: the one the schema refused too (a put refused there was dropped uncounted, and `hitch track`
    # could not say why its session went stale; a new user's report)
    assert r.states[-1]["track"]["rejected"] == 2
    assert "pose.z" in r.states[-1]["track"]["last_rejection"]
    assert _events(r, "track_setpoint_rejected")
    # a refused setpoint of another session, or of none, changes nothing
    assert not r.call("track/setpoint", {"session": session + 1, "seq": 100, "pose": {"z": "high"}})[0]
    for raw in (b"[1, 2]", b"\xff", b'{"session": true}'):
        assert not r.api.handle("track/setpoint", raw, None)[0]
    r.run(0.05)
    assert r.states[-1]["track"]["rejected"] == 2


@pytest.mark.parametrize(
    "payload, words",
    [
        ({"dof": ["z"], "ttl_ms": 20}, ["ttl_ms", ">= 50"]),
        ({"dof": ["z"], "ttl_ms": 5000}, ["ttl_ms", "<= 1000"]),
        ({"dof": []}, ["dof"]),
        ({"dof": ["z", "z"]}, ["dof", "at most once"]),
        ({"dof": ["yaw"]}, ["dof"]),
        ({"dof": ["z"], "frame": "world"}, ["frame"]),
    ],
)
def test_track_start_errors_name_the_field(payload, words):
    with pytest.raises(RequestError) as e:
        parse_request("track/start", json.dumps(payload))
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def test_viewers_cannot_track(model, tmp_path):
    policy = AccessPolicy(operators=("olga",), viewers=("vera",))
    rig = Rig(model, tmp_path, policy=policy)
    try:
        ok, reply = rig.call("track/start", {"dof": ["z"]}, user="vera")
        assert not ok and reply["error"] == "forbidden", reply
        ok, reply = rig.call("track/start", {"dof": ["z"]}, user="olga")
        assert ok, reply
        ok, reply = rig.setpoint(reply["session"], {"z": 0.2}, user="vera")
        assert not ok and reply["error"] == "forbidden"
        ok, reply = rig.call("track/stop", {}, user="vera")
        assert not ok and reply["error"] == "forbidden"
    finally:
        rig.store.close()
        rig.rig.close()


def test_level_frame_adds_the_tractor_attitude_and_needs_the_slope_sensor(r):
    ok, reply = r.call("track/start", {"dof": ["roll", "pitch"], "frame": "level"})
    assert not ok and reply["error"] == "unavailable" and "slope sensor" in reply["message"], reply
    r.sensors.att = (0.02, -0.01)  # tractor leans right 20 mrad (right side down), nose down 10 mrad
    session = r.start(dof=["roll", "pitch"], frame="level")
    ok, reply = r.setpoint(session, {"roll": 0.0, "pitch": 0.0})
    assert ok, reply
    target = r.states[-1]["track"]["target"] if r.states[-1]["track"] else None
    r.run(0.04)
    target = r.states[-1]["track"]["target"]
    # implement level: the hitch rolls its right side up by the lean, and leans the mast back by the nose-down
    assert target["roll"] == pytest.approx(0.02) and target["pitch"] == pytest.approx(-0.01)
    r.run(3.0, each=lambda t: r.setpoint(session, {"roll": 0.0, "pitch": 0.0}))
    m = r.measured()
    assert m[2] == pytest.approx(0.02, abs=2e-3) and m[3] == pytest.approx(-0.01, abs=2e-3)
    r.sensors.att = None  # the sensor falls silent: setpoints are refused, the stream goes stale
    ok, reply = r.setpoint(session, {"roll": 0.0, "pitch": 0.0})
    assert not ok and reply["error"] == "unavailable"
    r.run(1.0)
    assert r.states[-1]["motion"] is None


def test_ground_frame_commands_height_above_the_ground(r):
    r.sensors.dist = 0.30  # the implement's reference point is 0.30 m above the ground now
    session = r.start(dof=["z"], frame="ground")
    z_m = r.measured()[1]
    ok, reply = r.setpoint(session, {"z": 0.25})  # 5 cm lower above the ground
    assert ok, reply
    r.run(0.04)
    assert r.states[-1]["track"]["target"]["z"] == pytest.approx(z_m - 0.05, abs=1e-9)


def test_a_path_streamed_with_acceleration_and_jerk_is_taken_in_the_tractor_frame_only(r):
    """The Python API's path derivatives (the streaming client of a planned path): taken in frame tractor
    (the follower's target carries them), refused naming the frame in frame level."""
    session = r.start(dof=["z"])
    z0 = r.measured()[1]
    seq = 1
    r.mc.track_setpoint(session, seq, {"z": z0}, {"z": 0.0}, acceleration={"z": 0.05}, jerk={"z": 0.2})
    sp = r.mc._active.follower.setpoint
    assert sp.acceleration[1] == pytest.approx(0.05) and sp.jerk[1] == pytest.approx(0.2)
    r.mc.track_stop(session)
    r.run(1.0)
    r.sensors.att = (0.0, 0.0)
    level = r.start(dof=["roll"], frame="level")
    with pytest.raises(MotionError, match="only in frame tractor"):
        r.mc.track_setpoint(level, 1, {"roll": 0.0}, acceleration={"roll": 0.01})


def test_a_streamer_of_an_earlier_run_never_feeds_a_session_of_this_one(model, tmp_path):
    """A new user's report: session ids began at 1 in every run of the service, so after a restart a streamer
    left from before (its client reconnects by itself) fed a new client's session 1 and drove the hitch 135 mm
    from where that client held it. Ids now start at a random number: the old streamer's puts are refused."""
    first = Rig(model, tmp_path / "a")
    try:
        old = first.start()
    finally:
        first.store.close()
        first.rig.close()
    r = Rig(model, tmp_path / "b")
    try:
        session = r.start()
        assert session != old and 1 <= session <= 2**53
        z0 = r.measured()[1]
        ok, reply = r.setpoint(old, {"z": z0 + 0.05})
        assert not ok and reply["error"] == "not_found", reply
        r.setpoint(session, {"z": z0})
        r.run(1.0)
        assert abs(r.measured()[1] - z0) < 2e-3
    finally:
        r.store.close()
        r.rig.close()


def test_a_refused_setpoint_leaves_its_seq_and_field_errors_are_said_whatever_the_seq(r):
    """A new user's report: a refused setpoint used up its seq (the corrected resend was ignored as 'seq'), and
    an old seq with a malformed body was answered 'ignored: seq' instead of naming the field."""
    session = r.start(dof=["z"])
    z0 = r.measured()[1]
    ok, reply = r.setpoint(session, {"x": 0.0}, seq=5)
    assert not ok and "x not tracked" in reply["message"], reply
    ok, reply = r.setpoint(session, {"z": 0.9}, seq=6)
    assert not ok and "not a plausible SI value" in reply["message"], reply
    ok, reply = r.setpoint(session, {"z": z0}, seq=5)  # the corrected resend of 5 is taken
    assert ok and reply["accepted"], reply
    ok, reply = r.setpoint(session, {"z": z0, "x": 0.0}, seq=3)  # old seq, bad body: the field is named
    assert not ok and "x not tracked" in reply["message"], reply
    ok, reply = r.setpoint(session, {"z": z0}, seq=4)  # old seq, good body: ignored and counted
    assert ok and reply == {"accepted": False, "ignored": "seq", "session": session, "seq": 4}
    r.run(0.04)
    track = r.states[-1]["track"]
    assert track["setpoints"] == 1 and track["ignored_seq"] == 1 and track["rejected"] == 3, track


def test_a_ground_frame_setpoint_out_of_range_names_the_value_sent_and_the_range_in_its_frame(r):
    """A new user's report: frame ground refused z = 1.5 m as "setpoint.pose.z = 0.999268 m … allowed [-0.716,
    0.812] m", the converted tractor-frame value and range."""
    r.sensors.dist = 0.30
    session = r.start(dof=["z"], frame="ground")
    z_m = r.measured()[1]
    from planner.trajectory.track import PLAUSIBLE_MARGIN

    lo, hi = r.planner.lo[1] - PLAUSIBLE_MARGIN, r.planner.hi[1] + PLAUSIBLE_MARGIN  # the tractor frame's
    ok, reply = r.setpoint(session, {"z": 1.5})
    assert not ok and reply["error"] == "bad_request", reply
    shift = z_m - 0.30  # z_tractor = z_ground + (z_m - d)
    text = reply["message"]
    assert "setpoint.pose.z = 1.5 m in frame ground" in text, text
    assert f"allowed [{lo - shift:.3f}, {hi - shift:.3f}] m in frame ground" in text, text
    ok, _ = r.setpoint(session, {"z": 0.30})
    assert ok


def test_a_setpoint_after_the_stream_went_stale_says_the_session_is_over(r):
    """It said "resume() before streaming again", a method of the library's follower the service has no key
    for: the session brakes to rest and ends, a new one starts with track/start."""
    session = r.start(dof=["z"], ttl_ms=200)
    z0 = r.measured()[1]
    r.run(0.5, each=lambda t: r.setpoint(session, {"z": z0 + 0.05}))
    r.run(0.25)  # stale: braking, the session still live
    assert r.states[-1]["track"]["stale"] and r.states[-1]["track"]["session"] == session
    ok, reply = r.setpoint(session, {"z": z0})
    assert not ok, reply
    assert "went stale" in reply["message"] and "track/start starts a new one" in reply["message"], reply
    assert "resume()" not in reply["message"]


def test_a_stuck_ground_distance_sensor_does_not_drive_the_hitch_to_its_height_limit(r, model):
    """A CAN fuzz trial: the ground distance held at 0.30 m while a ground-frame session asked for 0.25 m —
    every setpoint asked for 5 cm lower again (positive feedback) and the hitch ran to z = −0.218 m, "height
    limit reached (bottom)". Now a reading that stays within 3 mm for 1 s while the hitch moves more than
    40 mm is taken for stuck: setpoints are refused naming it and the session brakes at its ttl."""
    message = _stuck_sensor_run(r, model, setpoint_m=0.25, seconds=6.0)
    assert "stayed at 0.300 m for 1.0 s" in message


def _stuck_sensor_run(r, model, setpoint_m: float, seconds: float) -> str:
    """A ground-frame session over a ground distance stuck at 0.30 m, ``setpoint_m`` asked for ``seconds``: it must
    be refused naming the stuck sensor, brake to rest, and stop well before the height limit. The first refusal."""
    r.sensors.dist = 0.30  # stuck: it never follows the hitch
    session = r.start(dof=["z"], frame="ground", ttl_ms=200)
    z0 = r.measured()[1]
    replies: list[tuple[bool, dict]] = []
    r.run(seconds, each=lambda t: replies.append(r.setpoint(session, {"z": setpoint_m})))
    refused = [rep for ok, rep in replies if not ok]
    assert refused and "stuck ground-distance sensor" in refused[0]["message"], replies[-1]
    assert r.states[-1]["motion"] is None  # braked to rest
    lo = r.states[-1]["pose"]["z"]
    workspace_min = model.workspace["z"][0]
    assert z0 - lo < 0.5 * (z0 - workspace_min), (z0, lo, workspace_min)  # stopped well before the limit
    return refused[0]["message"]


def test_a_stuck_ground_sensor_under_a_setpoint_a_few_millimetres_away_is_noticed_too(r, model):
    """A review of the fix above: under a setpoint 9 mm from the stuck reading (within the 10 mm a setpoint at
    its reading may ask) every setpoint asked for 9 mm lower again, and the hitch crept 333 mm to z = −0.218 m,
    the workspace's bottom limit, never refused. Now stuck once the hitch moved 120 mm with one reading."""
    _stuck_sensor_run(r, model, setpoint_m=0.291, seconds=20.0)


def test_one_setpoint_numbered_far_ahead_is_refused_and_the_live_stream_goes_on(r):
    """A fleet trial: another client put one setpoint with seq 2^53 into a live session; it was taken, every
    later setpoint of the session's own 50 Hz stream was ignored as old, and the session ended stale while its
    client streamed, told nothing. Now refused naming seq and its allowed range; the stream goes on."""
    session = r.start(dof=["z"], ttl_ms=200)
    z0 = r.measured()[1]
    r.run(0.5, each=lambda t: r.setpoint(session, {"z": z0}))
    ok, rep = r.setpoint(session, {"z": z0 + 0.08}, seq=2**53)
    assert not ok and rep["error"] == "bad_request", rep
    assert rep["message"].startswith("track/setpoint: seq = 9007199254740992"), rep
    assert "allowed:" in rep["message"], rep
    replies: list[tuple[bool, dict]] = []
    r.run(1.0, each=lambda t: replies.append(r.setpoint(session, {"z": z0 + 0.02})))
    assert all(ok and rep.get("accepted") for ok, rep in replies), replies[-1]
    assert r.states[-1]["track"]["session"] == session and r.states[-1]["track"]["ignored_seq"] == 0
    assert abs(r.measured()[1] - (z0 + 0.02)) < 0.005  # followed its own stream, never the far one


def test_setpoints_ignored_for_their_seq_are_announced_and_the_state_says_the_last_taken(r):
    """A fleet re-run: another client's one put with seq 1e9 (within the bound) had the session's own stream
    ignored until it went stale, and nothing said so. Now a track_setpoint_ignored event (at most one a second)
    names the seq taken, and the state's track says it (last_seq)."""
    session = r.start(dof=["z"], ttl_ms=300)
    z0 = r.measured()[1]
    r.run(0.2, each=lambda t: r.setpoint(session, {"z": z0}))
    ok, _ = r.setpoint(session, {"z": z0}, seq=10**9)  # the other client's
    assert ok
    r.run(0.5, each=lambda t: r.setpoint(session, {"z": z0}))  # ours, all below it now
    ignored = [e for e in r.events if e.get("event") == "track_setpoint_ignored"]
    assert len(ignored) == 1, ignored  # one a second
    assert f"is not above the last one session {session} took (1000000000): ignored" in ignored[0]["message"]
    assert "another client sending into this session" in ignored[0]["message"]
    tr = [s["track"] for s in r.states if s.get("track")][-1]  # the session went stale meanwhile: its last entry
    assert tr["last_seq"] == 10**9 and tr["ignored_seq"] > 5, tr
