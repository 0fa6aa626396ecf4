"""Headland sequences in a running service with the control core in its own process (the default
``control_core = "process"``): pause / resume / skip and teach-in through the core, the twin's GNSS
on ``hitch/tractor/gnss`` firing a line trigger while the simulated tractor drives, and lines kept
across a restart (the store)."""

from __future__ import annotations

import json
import math
import time

import pytest
import yaml

from bridge.service.client import HitchClient, ServiceError
from bridge.service.config import ServiceConfig
from bridge.service.gnss import LocalTangentPlane
from bridge.service.server import HitchService
from tests.helpers import wait_until
from tests.integration.service_process import free_port

pytestmark = pytest.mark.slow


def _start(tmp_path, **kw) -> tuple[HitchService, str]:
    ep = f"tcp/127.0.0.1:{free_port()}"
    cfg = ServiceConfig(listen=[ep], data_dir=tmp_path, planning_processes=1, **kw)
    svc = HitchService(cfg).start()
    try:
        assert wait_until(lambda: (svc.latest_state or {}).get("ecu", {}).get("online")), "no state from the core"
    except BaseException:
        svc.close()
        raise
    return svc, ep


@pytest.fixture
def service(tmp_path):
    svc, ep = _start(tmp_path)
    try:
        assert svc.core is not None and svc.motion is None  # the default: the core in its own process
        yield svc, ep
    finally:
        svc.close()


def _z(svc: HitchService) -> float:
    return float(svc.latest_state["pose"]["z"])


def _maneuver(svc: HitchService) -> dict | None:
    return svc.latest_state.get("maneuver")


def test_pause_resume_skip_and_teach_in_through_the_core_process(service):
    svc, ep = service
    events: list[dict] = []
    svc.add_listener("event", events.append)
    with HitchClient([ep], timeout_s=10) as c:
        acc = c.goto({"z": 0.0})
        c.wait_motion(acc["motion_id"], timeout_s=20)
        script = "steps:\n  - goto: {z: 0.3, speed_scale: 0.5}\n  - wait: 30\n  - goto: {z: 0.0}\n"
        c.request("maneuvers/save", {"name": "m", "script": script})
        c.request("maneuvers/run", {"name": "m"})
        assert wait_until(lambda: _z(svc) > 0.03, 10.0), "the first step did not start"
        r = c.request("maneuvers/pause", {})
        assert r["maneuver"]["paused"] is True and r["maneuver"]["step"] == 0, r
        assert wait_until(lambda: not svc.latest_state["moving"], 5.0), "the pause did not brake to rest"
        held = _z(svc)
        time.sleep(1.0)
        assert abs(_z(svc) - held) < 2e-3 and held < 0.28, held  # held short of the goal
        assert _maneuver(svc)["paused"] is True
        with pytest.raises(ServiceError) as e:
            c.request("maneuvers/pause", {})
        assert e.value.code == "busy"
        r = c.request("maneuvers/resume", {})
        assert r["maneuver"]["paused"] is False
        assert wait_until(lambda: (_maneuver(svc) or {}).get("step") == 1, 15.0), _maneuver(svc)
        assert wait_until(lambda: abs(_z(svc) - 0.3) < 5e-3, 5.0), _z(
            svc
        )  # re-planned from where it stood, to its goal
        m = _maneuver(svc)
        assert m["kind"] == "wait" and 20 < m["time_left"] <= 30, m
        r = c.request("maneuvers/skip", {})
        assert r["maneuver"]["step"] == 2, r
        assert wait_until(lambda: _maneuver(svc) is None, 15.0)
        assert wait_until(lambda: abs(_z(svc)) < 5e-3, 5.0), _z(svc)
        wanted = ("maneuver_paused", "maneuver_resumed", "maneuver_skipped", "maneuver_finished")
        # events and states reach this process by two subscriptions: the end's event may follow the state after it
        assert wait_until(lambda: all(n in [e.get("event") for e in events] for n in wanted), 5.0), [
            e.get("event") for e in events
        ]
        with pytest.raises(ServiceError) as e:
            c.request("maneuvers/skip", {})
        assert e.value.code == "not_found"

        # teach-in through the core: a goto, then a pause, then another goto
        assert c.request("maneuvers/record/start", {})["recording"] is True
        acc = c.goto({"z": 0.2, "x": 0.01})
        c.wait_motion(acc["motion_id"], timeout_s=20)
        time.sleep(0.8)
        acc = c.goto({"z": 0.05})
        c.wait_motion(acc["motion_id"], timeout_s=20)
        r = c.request("maneuvers/record/stop", {"name": "taught"})
        steps = [next(iter(s)) for s in yaml.safe_load(r["script"])["steps"]]
        assert steps[0] == "goto" and steps[-1] == "goto" and len(steps) == 3, r["script"]
        assert steps[1] in ("wait", "wait_for"), r["script"]  # the simulated tractor drives: maybe a distance
        assert r["saved"] == "taught"  # saved by record/stop; saved again, it must say so (replace)
        assert c.save_maneuver("taught", r["script"], replace=True) == {"saved": "taught", "steps": 3, "replaced": True}
        c.request("maneuvers/run", {"name": "taught"})
        assert wait_until(
            lambda: any(e.get("event") == "maneuver_finished" and e.get("maneuver") == "taught" for e in events), 30.0
        ), [e for e in events if str(e.get("event", "")).startswith("maneuver")][-4:]
        assert wait_until(lambda: abs(_z(svc) - 0.05) < 5e-3, 5.0), _z(svc)


def _line_across(plane: LocalTangentPlane, east_m: float) -> dict:
    a, b = plane.to_geodetic(east_m, -50.0), plane.to_geodetic(east_m, 50.0)
    return {"type": "LineString", "coordinates": [[a[1], a[0]], [b[1], b[0]]]}


@pytest.mark.parametrize("core", ["process", "thread"])
def test_the_twins_gnss_fires_a_line_trigger_in_a_running_service(tmp_path, core):
    origin, heading, speed = (48.1, 11.2), math.pi / 2, 4.0  # due east at 4 m/s
    svc, ep = _start(
        tmp_path,
        control_core=core,
        sim_ground_speed=speed,
        sim_gnss_origin=origin,
        sim_gnss_heading=heading,
    )
    fixes: list[dict] = []
    try:
        with HitchClient([ep], timeout_s=10) as c:
            sub = c.session.declare_subscriber(
                "hitch/tractor/gnss", lambda m: fixes.append(json.loads(m.payload.to_bytes()))
            )
            try:
                assert wait_until(lambda: len(fixes) >= 3, 10.0), "the twin publishes no GNSS"
                plane = LocalTangentPlane(*origin)
                e0, n0 = plane.to_local(fixes[-1]["lat"], fixes[-1]["lon"])
                assert abs(n0) < 0.05 and e0 > 0.0  # on the documented course: east of the origin
                assert abs(fixes[-1]["speed"] - speed) < 1e-9 and abs(fixes[-1]["heading"] - heading) < 1e-9
                line_e = e0 + 10.0  # 2.5 s ahead
                c.request("lines/save", {"name": "headland", "geojson": _line_across(plane, line_e)})
                acc = c.goto({"z": 0.0})
                c.wait_motion(acc["motion_id"], timeout_s=20)
                c.request(
                    "maneuvers/save",
                    {
                        "name": "h",
                        "script": "timeout: 60\nsteps:\n  - wait_for: {line: headland}\n  - goto: {z: 0.2}\n",
                    },
                )
                c.request("maneuvers/run", {"name": "h"})
                assert wait_until(lambda: (_maneuver(svc) or {}).get("step") == 1, 20.0), _maneuver(svc)
                east_at_step = plane.to_local(fixes[-1]["lat"], fixes[-1]["lon"])[0]
                assert line_e - 0.5 <= east_at_step <= line_e + 2.0, (east_at_step, line_e)  # at the line, 10 Hz fixes
                lines = c.request("lines/list", {})["lines"]
                assert lines[0]["name"] == "headland" and lines[0]["crossings"] == 1
            finally:
                sub.undeclare()
    finally:
        svc.close()


def test_lines_are_kept_across_a_restart_and_loaded_from_a_file(tmp_path):
    plane = LocalTangentPlane(48.0, 11.0)
    fc = {
        "type": "FeatureCollection",
        "features": [
            {"type": "Feature", "properties": {"name": "north"}, "geometry": _line_across(plane, 5.0)},
        ],
    }
    (tmp_path / "field.geojson").write_text(json.dumps(fc))
    svc, ep = _start(tmp_path, control_core="thread", lines_file=tmp_path / "field.geojson")
    try:
        with HitchClient([ep], timeout_s=10) as c:
            assert [ln["name"] for ln in c.request("lines/list", {})["lines"]] == ["north"]
            # an attacker's report: a bad GNSS put was dropped without trace anywhere; lines/list counts it now
            c.session.put("hitch/tractor/gnss", b'{"lat": NaN, "lon": 11}')
            assert wait_until(lambda: c.request("lines/list", {})["gnss"]["rejected"] == 1, 5.0)
            assert "lat" in c.request("lines/list", {})["gnss"]["last_rejection"]
            c.request("lines/save", {"name": "headland", "geojson": _line_across(plane, 30.0)})
            c.request("lines/save", {"name": "gone", "geojson": _line_across(plane, 40.0)})
            c.request("lines/delete", {"name": "gone"})
    finally:
        svc.close()
    svc, ep = _start(tmp_path)  # the process core, no file: the store's lines
    try:
        with HitchClient([ep], timeout_s=10) as c:
            lines = {ln["name"]: ln for ln in c.request("lines/list", {})["lines"]}
            assert set(lines) == {"north", "headland"}, lines
            want = _line_across(plane, 30.0)["coordinates"]
            assert lines["headland"]["coordinates"] == want
    finally:
        svc.close()


def test_a_saved_line_is_replaced_only_when_asked_and_one_in_use_is_deleted_only_with_force(tmp_path):
    """A field trial: ``lines/save`` of a name saved already replaced that headland line silently (a typo in a
    name moves where the hitch lifts), and ``lines/delete`` deleted a line a saved maneuver waits for (its
    run then aborts at the headland: trigger_unavailable). Now, as for maneuvers and presets: refused
    (``in_use``, nothing changed) unless ``replace`` / ``force``, and the reply says what was replaced or who
    used the deleted line."""
    plane = LocalTangentPlane(48.0, 11.0)
    svc, ep = _start(tmp_path, control_core="thread")
    try:
        with HitchClient([ep], timeout_s=10) as c:
            c.request("lines/save", {"name": "headland", "geojson": _line_across(plane, 30.0)})
            first = c.request("lines/list", {})["lines"][0]["coordinates"]
            with pytest.raises(ServiceError) as ei:
                c.request("lines/save", {"name": "headland", "geojson": _line_across(plane, 60.0)})
            assert ei.value.code == "in_use" and "'headland'" in str(ei.value) and "replace" in str(ei.value)
            assert c.request("lines/list", {})["lines"][0]["coordinates"] == first  # nothing changed
            r = c.request("lines/save", {"name": "headland", "geojson": _line_across(plane, 60.0), "replace": True})
            assert r["saved"] == ["headland"] and r["replaced"] == ["headland"]
            assert c.request("lines/list", {})["lines"][0]["coordinates"] == _line_across(plane, 60.0)["coordinates"]
            script = "steps:\n  - wait_for: {line: headland}\n  - goto: {z: 0.2}\n"
            c.request("maneuvers/save", {"name": "lift-at-headland", "script": script})
            with pytest.raises(ServiceError) as ei:
                c.request("lines/delete", {"name": "headland"})
            assert ei.value.code == "in_use" and "lift-at-headland" in str(ei.value) and "force" in str(ei.value)
            assert [ln["name"] for ln in c.request("lines/list", {})["lines"]] == ["headland"]
            r = c.request("lines/delete", {"name": "headland", "force": True})
            assert r["deleted"] == "headland" and r["maneuvers"] == ["lift-at-headland"] and "warning" in r
            assert c.request("lines/list", {})["lines"] == []
            with pytest.raises(ServiceError) as ei:  # a line never saved: not_found, as before
                c.request("lines/delete", {"name": "other", "force": True})
            assert ei.value.code == "not_found" and "other" in str(ei.value)
    finally:
        svc.close()


def test_two_saves_of_one_new_line_name_at_once_are_one_save_and_one_in_use(model, tmp_path):
    """A review: lines/save checked "saved already?" and then saved: two saves of one new name at once both
    passed the check and the second silently replaced the first. The check and the save are one step now."""
    import threading

    from tests.helpers import SimService

    s = SimService(model, tmp_path / "hitch.sqlite3")
    try:
        plane = LocalTangentPlane(48.0, 11.0)
        real = s.api.motion.lines_request

        def slow(*a, **k):  # the tracker's save takes a while (the core process's round trip)
            time.sleep(0.2)
            return real(*a, **k)

        s.api.motion.lines_request = slow
        answers: list[tuple[bool, dict]] = []

        def save(east: float) -> None:
            answers.append(s.call("lines/save", {"name": "headland", "geojson": _line_across(plane, east)}))

        threads = [threading.Thread(target=save, args=(e,)) for e in (30.0, 60.0)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(10)
        oks = [ok for ok, _ in answers]
        assert sorted(oks) == [False, True], answers
        refused = next(r for ok, r in answers if not ok)
        assert refused["error"] == "in_use", refused
    finally:
        s.close()
