"""Headland sequences: the line trigger in the language, GNSS line crossing (closed forms), lead
compensation in a short twin run, pause/resume/skip of a running maneuver, teach-in recording
replayed to the same poses, and the preset-delete refusal naming the maneuvers that use it."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bench.headland_bench import run_case
from bridge.service.gnss import GnssError, GnssTracker, LocalTangentPlane, parse_lines
from bridge.service.maneuvers.language import ManeuverError, PlanningContext, parse_maneuver, validate
from bridge.service.motion.controller import MotionController
from bridge.sim.move import SimRig
from planner.ik_qp.hitch_ik import IKSolver
from planner.limits.guard import Guard
from planner.trajectory import TrajectoryPlanner
from tests.helpers import SimService


# ------------------------------------------------------------------------------------------ language
def test_line_trigger_parses_and_carries_the_next_steps_planned_duration():
    s = parse_maneuver("steps:\n  - wait_for: {line: headland, complete: true}\n  - speed: 0.5\n  - goto: {z: 0.2}\n")
    assert s.steps[0].line == "headland" and s.steps[0].complete is True

    def plan(start, goal, scale):
        return 2.5, start

    from planner.trajectory import MotionState

    res = validate(s, PlanningContext(MotionState.at_rest(np.zeros(4)), plan, lambda n: None))
    assert res.ok and res.steps[0].line == "headland" and res.steps[0].lead_s == 2.5


@pytest.mark.parametrize(
    "script, message",
    [
        ("  - wait_for: {line: h, distance: 3}\n  - goto: {z: 0.1}\n", "exactly one of distance"),
        ("  - wait_for: {distance: 3, complete: true}\n", "complete is allowed only with line"),
        ("  - wait_for: {line: h, complete: true}\n  - wait: 1\n", "needs a motion step"),
        ("  - wait_for: {line: '-bad'}\n", "line name"),
        ("  - wait_for: {line: h, complete: 1}\n", "complete"),
    ],
)
def test_bad_line_triggers_are_refused_naming_the_field(script, message):
    with pytest.raises(ManeuverError) as e:
        parse_maneuver("steps:\n" + script)
    assert message in str(e.value)


# ------------------------------------------------------------------------------------------ gnss
def _line(plane, a, b, name="h"):
    (la, lo), (lb, lob) = plane.to_geodetic(*a), plane.to_geodetic(*b)
    return {
        "type": "Feature",
        "properties": {"name": name},
        "geometry": {"type": "LineString", "coordinates": [[lo, la], [lob, lb]]},
    }


def test_projection_round_trip_and_metres_per_degree():
    p = LocalTangentPlane(48.0, 11.0)
    e, n = p.to_local(48.001, 11.001)
    assert abs(n - 111.2) < 0.3 and abs(e - 74.6) < 0.3  # ~111.2 km per degree of latitude, × cos 48° east
    lat, lon = p.to_geodetic(e, n)
    assert abs(lat - 48.001) < 1e-10 and abs(lon - 11.001) < 1e-10


def test_a_straight_path_crosses_a_line_at_the_known_point():
    t = [0.0]
    g = GnssTracker(lambda: t[0], origin=(48.0, 11.0))
    g.save_lines(_line(g.plane, (5.0, -10.0), (5.0, 10.0)))  # a north-south line 5 m east
    # the path: north = 0.5 * east + 1 (heading east-north-east), 2 m/s along it
    for k in range(60):
        t[0] = 0.1 * k
        east = -2.0 + 0.1 * k * 2.0 / math.hypot(1, 0.5)
        g.take_fix({"east": east, "north": 0.5 * east + 1.0})
        if east < 5.0 and k > 0:  # (the first fix has no course yet)
            a = g.approach("h", t[0])
            assert a is not None and a.crossings == 0
            assert abs(a.distance_m - (5.0 - east) * math.hypot(1, 0.5)) < 1e-9  # along the course
            assert abs(a.speed_m_s - 2.0) < 1e-9
    assert g.crossings("h") == 1
    (_, ce, cn) = g.lines()[0]["crossed_at"]
    assert abs(ce - 5.0) < 1e-9 and abs(cn - 3.5) < 1e-9
    assert g.approach("h", t[0] + 5.0) is None  # stale


def test_one_outlier_fix_is_refused_and_never_crosses_a_line():
    """A field trial: one fix 1.5 km off was taken as two crossings of a line 150 m ahead and fired the headland
    step 148 m early. A fix no tractor could reach since the last one is refused and counted."""
    t = [0.0]
    g = GnssTracker(lambda: t[0], origin=(48.0, 11.0))
    g.save_lines(_line(g.plane, (150.0, -10.0), (150.0, 10.0)))  # 150 m east
    for k in range(10):  # 2.2 m/s east
        t[0] = 0.1 * k
        assert g.take_payload(json.dumps({"east": 0.22 * k, "north": 0.0}))
    t[0] = 1.0
    far_lat, far_lon = g.plane.to_geodetic(1500.0, 0.0)
    assert not g.take_payload(json.dumps({"lat": far_lat, "lon": far_lon}))
    assert "an outlier, not counted" in g.counts()["last_rejection"] and g.counts()["rejected"] == 1
    t[0] = 1.1
    assert g.take_payload(json.dumps({"east": 2.2, "north": 0.0}))  # the track goes on
    assert g.crossings("h") == 0


def test_fixes_far_from_the_lines_plane_are_refused_naming_the_lat_lon_order():
    """A field trial: lines saved in [lat, lon] order before the first fix set the plane; every correct fix then
    lay 5700 km away, was taken, and no line could ever be crossed."""
    g = GnssTracker(lambda: 0.0)
    g.save_lines({"type": "LineString", "coordinates": [[48.0, 11.0], [48.0, 11.001]]}, "swapped")
    assert not g.take_payload(json.dumps({"lat": 48.0, "lon": 11.0}))
    last = g.counts()["last_rejection"]
    assert "km from the plane's origin" in last and "[lat, lon] order" in last, last


def test_a_receiver_that_says_0_m_s_while_its_fixes_move_gets_the_fixes_speed():
    """A field trial: the twin's receiver sent speed 0 on a moving tractor; the course stayed unknown and the
    lead compensation of ``complete: true`` was off without a word."""
    t = [0.0]
    g = GnssTracker(lambda: t[0], origin=(48.0, 11.0))
    g.save_lines(_line(g.plane, (50.0, -10.0), (50.0, 10.0)))
    for k in range(5):
        t[0] = 0.1 * k
        lat, lon = g.plane.to_geodetic(0.2 * k, 0.0)
        g.take_fix({"lat": lat, "lon": lon, "speed": 0.0, "heading": math.pi / 2})
    a = g.approach("h", t[0])
    assert a is not None and a.distance_m is not None and abs(a.distance_m - 49.2) < 1e-6
    assert abs(a.speed_m_s - 2.0) < 1e-6


def test_closing_the_twins_receiver_waits_for_a_put_in_progress():
    """Defect (CI, stop 25): the twin's GNSS thread put on its Zenoh publisher while the service
    undeclared it ("RuntimeError: Already mutably borrowed" in thread twin-gnss): ``close`` returned at
    once. It now returns only after the put in progress has ended, and no put follows it."""
    import threading
    import time

    from bridge.service.gnss import TwinGnss

    in_put, ended, puts = threading.Event(), [], []

    def slow_put(data: bytes) -> None:
        puts.append(data)
        in_put.set()
        time.sleep(0.3)
        ended.append(time.monotonic())

    twin = TwinGnss(lambda: 1.0, lambda: 2.0)
    thread = twin.publish_every(slow_put, period_s=0.01)
    assert in_put.wait(5.0)
    twin.close()
    closed_at = time.monotonic()
    assert ended and ended[0] <= closed_at and not thread.is_alive()
    n = len(puts)
    time.sleep(0.05)
    assert len(puts) == n  # nothing put after close


def test_bad_lines_and_fixes_name_the_field():
    with pytest.raises(GnssError, match=r"coordinates\[1\]\[1\] \(lat\)"):
        parse_lines({"type": "LineString", "coordinates": [[11, 48], [11, 95]]}, "h")
    with pytest.raises(GnssError, match="LineString"):
        parse_lines({"type": "Polygon", "coordinates": []}, "h")
    g = GnssTracker(lambda: 0.0)
    assert not g.take_payload(b'{"lat": "x", "lon": 1}') and "lat" in (g.last_error or "")
    assert not g.take_payload(b"not json") and g.rejected == 2


@pytest.mark.parametrize(
    "coords, match",
    [
        ([[11, 48], [11, 48]], r"coordinates\[0\] and \[1\] are 0 m apart"),  # zero length
        ([[11, 48], [-169, -48]], r"coordinates\[1\] lies \d+\.\d km from the plane's origin"),  # antipodal
        ([[-180, 85], [180, -85]], r"coordinates\[1\] lies"),  # pole to pole
        ([[11, 48, 0], [11.001, 48, 1e308]], r"coordinates\[1\]\[2\] \(height, m\)"),
        ([[48, 11], [48, 11.001], [11, 48]], r"coordinates\[2\] lies"),  # a vertex in [lat, lon] order
    ],
)
def test_lines_the_plane_cannot_carry_are_refused_and_change_nothing(coords, match):
    """The old tracker saved all of these (its plane is only valid near its origin)."""
    g = GnssTracker(lambda: 0.0)
    with pytest.raises(GnssError, match=match):
        g.save_lines({"type": "LineString", "coordinates": coords}, "h")
    assert g.lines() == [] and g.plane is None  # all or none: no origin taken from a refused line
    assert g.save_lines({"type": "LineString", "coordinates": [[11, 48], [11.001, 48.001]]}, "ok") == ["ok"]


# ------------------------------------------------------------------------------------------ lead compensation (twin)
def test_lead_compensation_reaches_the_pose_at_the_line_at_12_kmh(model):
    with_lead = run_case(model, 12.0, lead=True)
    without = run_case(model, 12.0, lead=False)
    # "complete at the line": the pose within the tolerance the ECU settles to (one count per sensor)
    assert abs(with_lead["reference_within_tolerance_m"]) <= 0.3, with_lead
    assert with_lead["measured_at_pose_m"] is not None and abs(with_lead["measured_at_pose_m"]) <= 0.3, with_lead
    assert with_lead["planned_within_tolerance_s"] < with_lead["planned_duration_s"]
    # without it the pose is reached the planned duration × speed past the line
    assert without["reference_at_pose_m"] > 0.8 * without["planned_duration_s"] * 12 / 3.6, without


# ---------------------------------------------------------------------------------- pause / resume / skip (thread mode)
class _Svc(SimService):
    def __init__(self, model, tmp_path):
        super().__init__(model, tmp_path / "h.sqlite3", ik=IKSolver(model))

    def z(self):
        return self.states[-1]["pose"]["z"]


@pytest.fixture
def svc(model, tmp_path):
    s = _Svc(model, tmp_path)
    yield s
    s.close()


def test_pause_brakes_and_holds_resume_replans_skip_goes_on(svc):
    ok, _ = svc.call(
        "maneuvers/save", {"name": "m", "script": "steps:\n  - goto: {z: 0.3}\n  - wait: 30\n  - goto: {z: 0.0}\n"}
    )
    assert ok
    ok, r = svc.call("maneuvers/run", {"name": "m"})
    assert ok, r
    svc.run(0.6)
    ok, r = svc.call("maneuvers/pause")
    assert ok and r["maneuver"]["paused"] is True and r["maneuver"]["step"] == 0, r
    svc.run(1.5)
    held = svc.z()
    svc.run(1.0)
    assert abs(svc.z() - held) < 2e-3 and held < 0.28  # braked to rest short of the goal, holding
    assert not svc.states[-1]["moving"]
    ok, r = svc.call("maneuvers/pause")  # paused already: said once, not "maneuvers/pause: maneuvers/pause: pause: …"
    assert not ok and r["message"] == "maneuvers/pause: the maneuver is paused already", r
    ok, r = svc.call("maneuvers/resume")
    assert ok and r["maneuver"]["paused"] is False
    svc.run(4.0)
    assert abs(svc.z() - 0.3) < 5e-3  # the step re-planned from where it stood
    m = svc.states[-1]["maneuver"]
    assert m["step"] == 1 and m["kind"] == "wait" and 20 < m["time_left"] <= 30, m
    ok, r = svc.call("maneuvers/skip")
    assert ok and r["maneuver"]["step"] == 2, r
    svc.run(4.0)
    assert abs(svc.z()) < 5e-3 and svc.states[-1]["maneuver"] is None
    names = [e["event"] for e in svc.events]
    for n in ("maneuver_paused", "maneuver_resumed", "maneuver_skipped", "maneuver_finished"):
        assert n in names
    assert not svc.call("maneuvers/skip")[0]  # nothing runs


# ------------------------------------------------------------------------------------------ teach-in
def test_a_recorded_maneuver_replays_to_the_same_poses(svc):
    assert svc.call("presets/save", {"name": "work", "pose": {"z": -0.05}})[0]
    assert svc.call("maneuvers/record/start")[0]
    poses = []
    for key, payload in (("goto", {"goal": {"z": 0.25, "x": 0.02}}), ("presets/go", {"name": "work"})):
        ok, r = svc.call(key, payload)
        assert ok, r
        svc.run(r["duration"] + 1.2)
        poses.append(dict(svc.states[-1]["pose"]))
    for _ in range(15):  # jog up for 0.3 s
        assert svc.call("jog", {"vz": 0.1, "ttl_ms": 100})[0]
        svc.run(0.02)
    svc.run(1.5)
    poses.append(dict(svc.states[-1]["pose"]))
    ok, r = svc.call("maneuvers/record/stop", {"name": "taught"})
    assert ok, r
    # saved as the name says (it was only named in the script: a new user's report)
    assert r["saved"] == "taught" and "not_saved" not in r
    assert "taught" in [m["name"] for m in svc.call("maneuvers/list")[1]["maneuvers"]]
    script = r["script"]
    kinds = [next(iter(s)) for s in parse_maneuver(script).to_json()["steps"]]
    assert kinds[0] == "goto" and "preset" in kinds and kinds[-1] == "goto" and "wait" in kinds, script
    assert svc.call("goto", {"goal": {"z": 0.1, "x": 0.0}})[0]
    svc.run(3.0)
    # saved by record/stop already: saving it again replaces it only when asked to
    assert svc.call("maneuvers/save", {"name": "taught", "script": script})[1]["error"] == "in_use"
    assert svc.call("maneuvers/save", {"name": "taught", "script": script, "replace": True})[1]["replaced"] is True
    ok, r = svc.call("maneuvers/run", {"name": "taught"})
    assert ok, r
    seen = {}
    for _ in range(600):
        svc.run(0.1)
        m = svc.states[-1]["maneuver"]
        if m is None:
            break
        seen.setdefault(m["step"], None)
    assert svc.states[-1]["maneuver"] is None
    end = svc.states[-1]["pose"]
    for k in ("x", "z"):
        assert abs(end[k] - poses[-1][k]) < 5e-3, (end, poses[-1])


# ------------------------------------------------------------------------------------------ preset delete
def test_a_wait_for_a_line_no_one_saved_fails_validation_naming_the_step_and_the_saved_lines(svc):
    """A new user's report: it validated (ok, errors []), run was accepted, and the maneuver aborted at once
    with trigger_unavailable."""
    script = "steps:\n  - wait_for: {line: nope}\n  - goto: {z: 0.1}\n"
    ok, r = svc.call("maneuvers/validate", {"script": script})
    assert ok and not r["ok"], r
    assert r["errors"] == [{"step": 0, "message": "wait_for.line: no line 'nope' is saved (lines/save; saved: none)"}]
    assert svc.call("maneuvers/save", {"name": "w", "script": script})[0]  # a line may be saved later
    ok, r = svc.call("maneuvers/run", {"name": "w"})
    assert not ok and r["error"] == "invalid" and "no line 'nope' is saved" in r["message"], r
    # named as validate's CLI and the page name it (the refusal said "step 0" where they say "step 1")
    assert "validate from the current pose: step 1 (index 0): wait_for.line: no line" in r["message"], r
    svc.api.store.save_line("nope", [[11.0, 48.0], [11.001, 48.0]])
    ok, r = svc.call("maneuvers/validate", {"script": script})
    assert ok and r["ok"], r


def test_a_maneuver_at_rest_refuses_implement_and_mode_changes_saying_so(svc):
    """A new user's report: with a maneuver paused and the hitch at rest, both were refused "while the hitch is
    moving"."""
    assert svc.call("implements/define", {"name": "h", "category": "2", "mass_kg": 500.0, "com_m": [0, 0.5, 0.3]})[0]
    assert svc.call("maneuvers/save", {"name": "idle", "script": "steps:\n  - wait: 5\n"})[0]
    assert svc.call("maneuvers/run", {"name": "idle"})[0]
    svc.run(0.3)
    assert svc.states[-1]["maneuver"] is not None and not svc.states[-1]["moving"]
    ok, r = svc.call("implements/select", {"name": "h"})
    assert not ok and r["error"] == "busy" and "while maneuver idle runs (paused or not)" in r["message"], r
    ok, r = svc.call("mode", {"mode": "manual"})
    assert not ok and r["error"] == "busy" and "while maneuver idle runs" in r["message"], r
    assert "moving" not in r["message"]


def test_deleting_a_preset_a_maneuver_uses_is_refused_unless_forced(svc):
    assert svc.call("presets/save", {"name": "work", "pose": {"z": 0.1}})[0]
    assert svc.call("maneuvers/save", {"name": "lift", "script": "steps:\n  - preset: work\n"})[0]
    assert svc.call("maneuvers/save", {"name": "other", "script": "steps:\n  - goto: {z: 0.1}\n"})[0]
    ok, r = svc.call("presets/delete", {"name": "work"})
    assert not ok and r["error"] == "in_use" and "lift" in r["message"] and "other" not in r["message"]
    ok, r = svc.call("presets/delete", {"name": "work", "force": True})
    assert ok and r["deleted"] == "work" and r["maneuvers"] == ["lift"] and "lift" in r["warning"]


# ------------------------------------------------------------------------------------------ skip while planning
def test_a_plan_made_for_a_skipped_step_is_not_installed(model):
    """Skip pressed while step 0's plan is being made: that plan (for z 0.3) must not start, nor be
    taken as the motion of step 1 (z 0.1); step 1 runs to its own goal."""
    rig = SimRig(model)
    rig.start()
    rig.run_until(0.5)
    pending: list = []
    states: list = []
    mc = MotionController(
        Guard(TrajectoryPlanner(model)),
        Guard(TrajectoryPlanner(model)),
        rig.link,
        lambda: rig.now_s,
        on_state=states.append,
        spawn=pending.append,  # planning is held back until the test runs it
    )
    try:

        def run(seconds):
            end = rig.now_s + seconds
            while rig.now_s < end - 1e-9:
                rig.run_until(rig.now_s + 0.02)
                mc.cycle()
                while pending and not held:
                    pending.pop(0)()

        held = False
        mc.cycle()
        acc = mc.goto({"z": 0.0})
        run(acc.duration + 1.0)
        script = "steps:\n  - goto: {z: 0.3}\n  - goto: {z: 0.1}\n"
        res = validate(script, PlanningContext(mc.current_state(), mc.plan_step, lambda n: None))
        assert res.ok, res.errors
        held = True
        mc.run_maneuver(res, "two")
        run(0.04)
        assert len(pending) == 1  # step 0 asked for its plan
        stale = pending.pop()
        mc.maneuver_control("skip")
        run(0.04)
        assert len(pending) == 1  # step 1 asked for its plan
        stale()  # the plan of the skipped step comes back now
        held = False
        run(6.0)
        assert states[-1]["maneuver"] is None
        assert abs(states[-1]["pose"]["z"] - 0.1) < 5e-3, states[-1]["pose"]  # step 1's goal, not step 0's
        assert max(s["pose"]["z"] for s in states) < 0.12  # never headed for 0.3
    finally:
        rig.close()


def test_a_lines_file_that_is_not_utf8_is_a_gnss_error_naming_it(tmp_path):
    """The old start-up read it with open(...).read(): a UnicodeDecodeError ended the service with a traceback."""
    from types import SimpleNamespace

    from bridge.service.gnss import restore_lines

    f = tmp_path / "field.geojson"
    f.write_bytes(b'{"type": "LineString", "coordinates": [[11, 48], [11.001, 48]], "name": "caf\xe9"}')
    api = SimpleNamespace(store=SimpleNamespace(list_lines=lambda: []), motion=None)
    with pytest.raises(GnssError, match=r"lines_file .*field\.geojson: not UTF-8 text \(byte \d+, line 1"):
        restore_lines(api, f)


def test_the_twins_receiver_goes_on_after_a_put_that_failed():
    """A put that raised ended the twin's GNSS thread for good (no more fixes, silently); now it is counted and the
    next fix is put."""
    import threading

    from bridge.service.gnss import TwinGnss

    puts: list[bytes] = []
    enough = threading.Event()

    def flaky_put(data: bytes) -> None:
        if len(puts) < 2:
            puts.append(b"")
            raise RuntimeError("congested")
        puts.append(data)
        if len(puts) >= 5:
            enough.set()

    twin = TwinGnss(lambda: 1.0, lambda: 2.0)
    thread = twin.publish_every(flaky_put, period_s=0.01)
    try:
        assert enough.wait(5.0), puts
    finally:
        twin.close()
    assert twin.put_failures == 2 and twin.last_error == "RuntimeError: congested"
    assert all(json.loads(p)["speed"] == 2.0 for p in puts[2:5])
    assert not thread.is_alive()


@pytest.mark.parametrize(
    "geojson, said",
    [
        ({"coordinates": [[11.0, 48.0], [11.001, 48.0]]}, "got no type"),
        ({"type": "Nope"}, "got 'Nope'"),
        (
            {"type": "Feature", "geometry": {"coordinates": []}},
            "geojson.geometry.type must be 'LineString', got no type",
        ),
    ],
)
def test_a_geojson_type_that_is_missing_is_said_so_never_as_python_none(geojson, said):
    """A fleet trial: lines/save of an object without a type said "… got None"."""
    with pytest.raises(GnssError) as err:
        parse_lines(geojson, "l")
    assert said in str(err.value) and "None" not in str(err.value), err.value
