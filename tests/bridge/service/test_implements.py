"""Implements at runtime and the quick raise / return, through ``ServiceAPI.handle``: define, list and
select (the guards get the implement's mass, CoM and limits; presets follow the implement), refused
while moving, persisted across a store reopen, the store's migration from schema version 2, the
transport lock, the upper height limit, and raise / return with the core in threads (simulated CAN rig
in simulated time) and in its own process (the default)."""

from __future__ import annotations

import json
import sqlite3
import time

import numpy as np
import pytest

from bridge.service.config import ServiceConfig
from bridge.service.implements import HEADLAND_PRESET
from bridge.service.motion.controller import STOP_GRACE_S
from bridge.service.server import HitchService
from bridge.service.store import MIGRATIONS, SCHEMA_VERSION, HitchStore
from bridge.service.workers import PlanningWorkers, WorkerSpec
from planner.limits.implement_limits import LOWERING_SPEED_LIMIT, UPPER_HEIGHT_LIMIT
from planner.trajectory import TrajectoryPlanner
from tests.helpers import SimService, wait_until
from tests.integration.service_process import free_port

HARROW = {"name": "harrow", "category": "2", "mass_kg": 1200.0, "com_m": [0.0, 0.6, 0.4]}
HEADLAND = {"x": 0.0, "z": 0.25, "roll": 0.0, "pitch": 0.0}
WORK = {"x": 0.02, "z": -0.05, "roll": 0.0, "pitch": 0.0}


class Service(SimService):
    def __init__(self, model, path, planning=None):
        super().__init__(model, path, planning=planning)

    def pose(self) -> np.ndarray:
        return self.mc.current_state().position


@pytest.fixture
def svc(model, tmp_path):
    s = Service(model, tmp_path / "hitch.sqlite3")
    yield s
    s.close()


def test_define_list_select_gives_the_guards_the_implement(svc):
    r = svc.ok("implements/define", {**HARROW, "upper_height_m": 0.28, "lowering_speed_m_s": 0.05})
    assert r["defined"] == "harrow" and r["implement"]["upper_height_m"] == 0.28
    listed = svc.ok("implements/list")
    by_name = {i["name"]: i for i in listed["implements"]}
    assert by_name["harrow"]["source"] == "store" and by_name["harrow"]["mass_kg"] == 1200.0
    assert by_name["cat2-power-harrow-1500"]["source"] == "profile"  # the tractor profile's records are offered
    assert listed["selected"] == "default"
    assert svc.mc.guard.implement is None
    svc.ok("implements/select", {"name": "harrow"})
    for g in (svc.mc.guard, svc.mc.plan_guard):
        assert g.implement.mass == 1200.0 and g.implement.centre_of_mass == (0.0, 0.6, 0.4)
        assert g.implement_limits.upper_height_m == 0.28 and g.implement_limits.lowering_speed_m_s == 0.05
    assert svc.ok("implements/list")["selected"] == "harrow"
    assert svc.api.info["implement"] == "harrow" and svc.ok("config")["implement"] == "harrow"
    # a profile record can be selected too (stored first, no limits)
    svc.ok("implements/select", {"name": "cat2-power-harrow-1500"})
    assert svc.mc.guard.implement.name == "cat2-power-harrow-1500" and svc.mc.guard.implement.mass == 1500.0
    assert svc.mc.guard.implement_limits.upper_height_m is None


@pytest.mark.parametrize(
    "payload, field",
    [
        ({**HARROW, "mass_kg": 0}, "mass_kg"),
        ({**HARROW, "category": "5"}, "category"),
        ({**HARROW, "com_m": [0.0, 0.6]}, "com_m"),
        ({**HARROW, "com_m": [0.0, 60.0, 0.0]}, "com_m"),
        ({**HARROW, "upper_height_m": 3.0}, "upper_height_m"),
        ({**HARROW, "lowering_speed_m_s": -0.1}, "lowering_speed_m_s"),
        ({**HARROW, "headland": {"x": 0.0, "z": 0.2}}, "headland"),
        ({**HARROW, "name": "../x"}, "name"),
    ],
)
def test_define_is_validated_naming_the_field(svc, payload, field):
    ok, r = svc.call("implements/define", payload)
    assert not ok and r["error"] == "bad_request" and field in r["message"]


def test_a_headland_pose_outside_the_workspace_is_refused_naming_the_range(svc):
    """A new user's report: a headland at z = 0.5 m (workspace top 0.31 m) was accepted; every raise to it then
    failed. Now the definition is refused, naming the DOF and its range, and nothing is stored."""
    tp = svc.mc.planner
    svc.api.info["limits"] = {"workspace": {k: list(tp.workspace[k]) for k in ("x", "z", "roll", "pitch")}}  # as served
    ok, r = svc.call(
        "implements/define", {**HARROW, "name": "high", "headland": {"x": 0.0, "z": 0.5, "roll": 0.0, "pitch": 0.0}}
    )
    assert not ok and r["error"] == "unreachable", r
    assert "headland" in r["message"] and "workspace:z:max" in r["message"], r["message"]
    assert "high" not in [i["name"] for i in svc.ok("implements/list")["implements"]]


def test_select_of_an_unknown_implement_and_deleting_the_selected_one_are_refused(svc):
    ok, r = svc.call("implements/select", {"name": "nope"})
    assert not ok and r["error"] == "not_found" and "nope" in r["message"]
    svc.ok("implements/define", HARROW)
    svc.ok("implements/select", {"name": "harrow"})
    ok, r = svc.call("implements/delete", {"name": "harrow"})
    assert not ok and "selected" in r["message"]
    svc.ok("implements/define", {**HARROW, "name": "other"})
    assert svc.ok("implements/delete", {"name": "other"}) == {"deleted": "other"}


def test_presets_follow_the_selected_implement(svc):
    svc.ok("implements/define", HARROW)
    svc.ok("implements/define", {**HARROW, "name": "plough", "mass_kg": 900.0})
    svc.ok("implements/select", {"name": "harrow"})
    svc.ok("presets/save", {"name": "work", "pose": {"z": 0.1}})
    assert [p["name"] for p in svc.ok("presets/list")["presets"]] == ["work"]
    svc.ok("implements/select", {"name": "plough"})
    assert svc.ok("presets/list") == {"presets": [], "implement": "plough"}
    ok, r = svc.call("presets/go", {"name": "work"})
    assert not ok and r["error"] == "not_found" and "plough" in r["message"]
    svc.ok("implements/select", {"name": "harrow"})
    assert svc.ok("presets/list")["implement"] == "harrow"
    assert svc.store.get_preset("work", implement="harrow") is not None


def test_default_selects_no_implement_again(svc):
    """A field operator's report: after selecting an implement there was no way back to none ("no implement
    'default'"), so the presets saved without one could not be reached again."""
    svc.ok("presets/save", {"name": "work", "pose": {"z": 0.1}})  # kept under "default"
    svc.ok("implements/define", {**HARROW, "upper_height_m": 0.28})
    svc.ok("implements/select", {"name": "harrow"})
    assert svc.ok("implements/select", {"name": "default"}) == {"selected": "default", "implement": None}
    for g in (svc.mc.guard, svc.mc.plan_guard):
        assert g.implement is None and g.implement_limits.upper_height_m is None
    assert svc.ok("implements/list")["selected"] == "default" and svc.ok("config")["implement"] is None
    assert [p["name"] for p in svc.ok("presets/list")["presets"]] == ["work"]
    ok, r = svc.call("implements/select", {"name": "nope"})
    assert not ok and "'default' selects none" in r["message"]


def test_a_preset_above_the_implements_upper_height_is_not_saved(svc):
    """An engineer's report: it was saved and refused only at presets/go."""
    svc.ok("implements/define", {**HARROW, "upper_height_m": 0.28})
    svc.ok("implements/select", {"name": "harrow"})
    ok, r = svc.call("presets/save", {"name": "high", "pose": {"z": 0.30}})
    assert not ok and r["error"] == "unreachable", r
    assert "pose.z = 0.3000 m is above the upper height of the implement 'harrow', 0.28 m" in r["message"]
    assert svc.ok("presets/list")["presets"] == []
    svc.ok("presets/save", {"name": "ok", "pose": {"z": 0.27}})


def test_an_implement_of_another_category_is_not_selected(svc):
    """An engineer's report: a category 2 implement was selected on a category 3 hitch."""
    assert svc.mc.planner.model.category == "2"
    svc.ok("implements/define", {**HARROW, "name": "wide", "category": "3"})  # defining one is allowed
    ok, r = svc.call("implements/select", {"name": "wide"})
    assert not ok and r["error"] == "bad_request", r
    assert "'wide' is an ISO 730 category 3 implement; this hitch is set up for category 2" in r["message"]
    assert svc.mc.guard.implement is None and svc.ok("implements/list")["selected"] == "default"


def test_redefining_the_selected_implement_in_another_category_is_refused_and_nothing_changes(svc):
    """A new user's report: redefining the selected category-2 implement as category 3 was taken and applied
    (the select's category check skipped); after a restart the service silently ran without it."""
    svc.ok("implements/define", HARROW)
    svc.ok("implements/select", {"name": "harrow"})
    ok, r = svc.call("implements/define", {**HARROW, "category": "3", "mass_kg": 900.0})
    assert not ok and r["error"] == "bad_request", r
    assert r["message"].startswith("implements/define: 'harrow' is an ISO 730 category 3 implement"), r
    harrow = next(i for i in svc.ok("implements/list")["implements"] if i["name"] == "harrow")
    assert harrow["category"] == "2" and harrow["mass_kg"] == 1200.0 and svc.mc.guard.implement.mass == 1200.0


def test_a_headland_above_the_implement_s_upper_height_is_refused_at_definition(svc):
    """A new user's report: accepted, then every quick raise was refused at the upper height."""
    tp = svc.mc.planner
    svc.api.info["limits"] = {"workspace": {k: list(tp.workspace[k]) for k in ("x", "z", "roll", "pitch")}}
    payload = {**HARROW, "name": "t1", "upper_height_m": 0.2, "headland": {**HEADLAND, "z": 0.3}}
    ok, r = svc.call("implements/define", payload)
    assert not ok and r["error"] == "bad_request", r
    assert "headland.z = 0.3 m is above upper_height_m = 0.2 m" in r["message"], r
    assert "t1" not in [i["name"] for i in svc.ok("implements/list")["implements"]]
    assert svc.call("implements/define", {**payload, "headland": {**HEADLAND, "z": 0.2}})[0]  # at it: taken


def test_the_name_default_is_reserved(svc):
    """A new user's report: an implement named 'default' could be defined; while no implement was selected
    ("default") it was applied, changing the checks while the config said none was selected."""
    svc.ok("implements/select", {"name": "default"})
    ok, r = svc.call("implements/define", {**HARROW, "name": "default", "upper_height_m": 0.0})
    assert not ok and r["error"] == "bad_request" and "name 'default' is reserved" in r["message"], r
    assert svc.mc.guard.implement is None and "default" not in [
        i["name"] for i in svc.ok("implements/list")["implements"]
    ]


def test_a_refused_select_of_a_tractor_profile_implement_changes_nothing(svc):
    """A field trial: selecting a tractor profile's implement while moving was refused, yet the list showed it as
    stored ("store", no longer "profile") afterwards."""
    builtin = [i for i in svc.ok("implements/list")["implements"] if i["source"] == "profile"]
    assert builtin, "the tractor profile lists implements"
    name = builtin[0]["name"]
    svc.ok("goto", {"goal": {"z": 0.25}})
    svc.run(0.1)
    ok, r = svc.call("implements/select", {"name": name})
    assert not ok and r["error"] == "busy", r
    after = {i["name"]: i["source"] for i in svc.ok("implements/list")["implements"]}
    assert after[name] == "profile", after
    svc.run(5.0)
    svc.ok("implements/select", {"name": name})  # at rest: taken, and stored from then on
    assert {i["name"]: i["source"] for i in svc.ok("implements/list")["implements"]}[name] == "store"


def test_changing_the_implement_while_moving_is_refused(svc):
    svc.ok("implements/define", HARROW)
    svc.ok("goto", {"goal": {"z": 0.25}})
    svc.run(0.1)
    ok, r = svc.call("implements/select", {"name": "harrow"})
    assert not ok and r["error"] == "busy" and "moving" in r["message"]
    assert svc.mc.guard.implement is None and svc.ok("implements/list")["selected"] == "default"
    svc.run(5.0)
    svc.ok("implements/select", {"name": "harrow"})  # at rest: taken
    ok, r = svc.call("implements/define", {**HARROW, "mass_kg": 1300.0})  # redefining the selected one: applied
    assert ok and svc.mc.guard.implement.mass == 1300.0


def test_selection_limits_and_work_pose_survive_a_store_reopen(model, tmp_path):
    path = tmp_path / "hitch.sqlite3"
    a = Service(model, path)
    try:
        a.ok("implements/define", {**HARROW, "upper_height_m": 0.27, "headland": HEADLAND})
        a.ok("implements/select", {"name": "harrow"})
        a.ok("goto", {"goal": {"z": WORK["z"], "x": WORK["x"]}})
        a.run(5.0)
        a.ok("hitch/raise")
        a.run(5.0)
        a.ok("implements/lock")
    finally:
        a.close()
    b = Service(model, path)  # a new service on the same database (a restart)
    try:
        assert b.ok("implements/list")["selected"] == "harrow" and b.api.implement == "harrow"
        assert b.mc.guard.implement.mass == 1200.0 and b.mc.guard.implement_limits.upper_height_m == 0.27
        assert b.mc.guard.implement_limits.transport_locked
        imp = b.store.get_implement("harrow")
        assert imp is not None and imp.last_work is not None
        assert imp.last_work["z"] == pytest.approx(WORK["z"], abs=1e-6)
    finally:
        b.close()


def test_the_store_migrates_from_schema_version_2(tmp_path):
    path = tmp_path / "old.sqlite3"
    db = sqlite3.connect(path, isolation_level=None)
    for migration in MIGRATIONS[:2]:  # what the previous program created
        for statement in migration.split(";"):
            if statement.strip():
                db.execute(statement)
    db.execute("PRAGMA user_version = 2")
    db.execute(
        "INSERT INTO presets (implement, name, x, z, roll, pitch, speed_scale, updated_s, owner) "
        "VALUES ('harrow', 'work', 0.0, 0.1, 0.0, 0.0, NULL, 1.0, '')"
    )
    db.close()
    assert SCHEMA_VERSION >= 3  # 2 → 3 added the implements (later versions may follow)
    with HitchStore(path) as store:
        assert store.schema_version == SCHEMA_VERSION
        assert store.get_preset("work", implement="harrow").pose["z"] == 0.1  # kept
        assert store.list_implements() == [] and store.get_setting("selected_implement") is None


def test_transport_lock_refuses_every_motion_but_stop(svc):
    svc.ok("implements/define", {**HARROW, "headland": HEADLAND})
    svc.ok("implements/select", {"name": "harrow"})
    svc.ok("presets/save", {"name": "p", "pose": {"z": 0.1}})
    assert svc.ok("implements/lock") == {"implement": "harrow", "transport_locked": True}
    start = svc.pose().copy()
    for key, payload in (
        ("goto", {"goal": {"z": 0.2}}),
        ("jog", {"vz": 0.05}),
        ("presets/go", {"name": "p"}),
        ("hitch/raise", {}),
        ("track/start", {"dof": ["z"]}),
    ):
        ok, r = svc.call(key, payload)
        assert not ok and r["error"] == "locked" and "transport-locked" in r["message"], key
        assert r["message"].startswith(key) and not r["message"].startswith(f"{key}: {key} "), r["message"]
        # the CLI command too, not only the API key (a new user's trial)
        assert r["message"].endswith(
            "transport-locked (unlock it first: `hitch implement unlock`, key implements/unlock; stop is allowed)"
        ), r["message"]
    assert svc.call("stop")[0]
    svc.run(0.5)
    np.testing.assert_allclose(svc.pose(), start, atol=1e-9)  # nothing moved
    svc.ok("implements/unlock")
    time.sleep(STOP_GRACE_S + 0.02)  # a goto that arrives just after a stop may have been sent before it
    assert svc.ok("goto", {"goal": {"z": 0.2}})["accepted"]


def test_the_upper_height_limit_refuses_a_goto_naming_it(svc):
    svc.ok("implements/define", {**HARROW, "upper_height_m": 0.2})
    svc.ok("implements/select", {"name": "harrow"})
    ok, r = svc.call("goto", {"goal": {"z": 0.25}})
    assert not ok and r["error"] == "refused" and UPPER_HEIGHT_LIMIT in r["message"]
    assert svc.ok("goto", {"goal": {"z": 0.19}})["accepted"]


def test_a_track_session_obeys_the_upper_height_and_lowering_speed_limits(svc):
    """Streamed setpoints above the upper height limit, then far below with a fast setpoint velocity: no
    streamed reference above the limit, no downward z speed above the lowering speed limit (finite
    differences of the streamed references over the state messages' clock), both limits named."""
    upper, lowering = 0.2, 0.04
    svc.ok("implements/define", {**HARROW, "upper_height_m": upper, "lowering_speed_m_s": lowering})
    svc.ok("implements/select", {"name": "harrow"})
    session = svc.ok("track/start", {"dof": ["z"], "ttl_ms": 300})["session"]
    seq = iter(range(1, 100000))

    def send(pose, velocity=None):
        body = {"session": session, "seq": next(seq), "pose": pose}
        if velocity is not None:
            body["velocity"] = velocity
        return svc.ok("track/setpoint", body)

    assert send({"z": 0.3})["limited"] == {"z": UPPER_HEIGHT_LIMIT}
    svc.run(5.0, each=lambda: send({"z": 0.3}, {"z": 0.05}))
    assert UPPER_HEIGHT_LIMIT in svc.states[-1]["track"]["control_limited"].values()
    assert abs(svc.pose()[1] - upper) < 3e-3  # it went up to the limit and stayed there
    reply = send({"z": -0.1}, {"z": -0.4})
    assert reply["limited"].get("vz") == LOWERING_SPEED_LIMIT
    svc.run(3.0, each=lambda: send({"z": -0.1}, {"z": -0.4}))
    assert svc.states[-1]["motion"] == "track"
    refs = [(s["clock"], s["reference"]["pose"]["z"]) for s in svc.states if s.get("reference") is not None]
    t, z = np.array(refs).T
    assert z.max() <= upper + 1e-6, z.max()
    keep = np.diff(t) > 1e-6
    vz = np.diff(z)[keep] / np.diff(t)[keep]
    assert -vz.min() <= lowering * 1.001, vz.min()
    assert z[-1] < upper - 0.08  # it did descend (3 s at up to 0.04 m/s)
    assert svc.call("stop")[0]


def test_sim_switch_without_a_twin_is_unavailable_and_the_position_is_validated(svc):
    ok, r = svc.call("sim/switch", {"position": "raise"})
    assert not ok and r["error"] == "unavailable" and "simulated tractor" in r["message"], r
    ok, r = svc.call("sim/switch", {"position": "up"})
    assert not ok and r["error"] == "bad_request" and "position" in r["message"], r


HEAVY = {"name": "heavy", "category": "2", "mass_kg": 1500.0, "com_m": [0.0, 1.0, 0.5]}


def test_the_planning_processes_plan_with_the_selected_implement(model, tmp_path):
    """``plan`` and ``maneuvers/validate`` in a planning process: after selecting a heavy implement a
    goto its guard refuses (front axle load) is refused by the preview and the validation as by the goto
    itself; the upper height limit likewise; selecting back to a light one lets them through again."""
    workers = PlanningWorkers(WorkerSpec("thesis-t132", "2", TrajectoryPlanner(model).rate, None), 1).start()
    svc = Service(model, tmp_path / "hitch.sqlite3", planning=workers)
    try:
        workers.warm(60.0)
        svc.ok("goto", {"goal": {"z": 0.2}})
        svc.run(4.0)
        assert svc.mc.current_state().position[1] == pytest.approx(0.2, abs=1e-6) and not svc.mc.current_state().moving
        down = {"goal": {"z": 0.1}}
        low_script = {"script": "steps: [{goto: {z: 0.1}}]"}
        assert svc.ok("plan", down)["ok"]  # the configured (no) implement: fine
        assert svc.ok("maneuvers/validate", low_script)["ok"]
        svc.ok("implements/define", {**HEAVY, "upper_height_m": 0.25})
        svc.ok("implements/select", {"name": "heavy"})
        preview = svc.ok("plan", down)
        assert not preview["ok"] and "front_axle_load" in json.dumps(preview["reasons"]), preview
        assert not svc.ok("maneuvers/validate", low_script)["ok"]
        ok, r = svc.call("goto", down)  # the goto itself: refused the same way
        assert not ok and r["error"] == "refused" and "front_axle_load" in r["message"], r
        preview = svc.ok("plan", {"goal": {"z": 0.28}})  # the selected implement's upper height limit
        assert not preview["ok"] and UPPER_HEIGHT_LIMIT in json.dumps(preview["reasons"]), preview
        svc.ok("implements/define", {**HARROW, "mass_kg": 300.0})
        svc.ok("implements/select", {"name": "harrow"})
        assert svc.ok("plan", down)["ok"] and svc.ok("plan", {"goal": {"z": 0.28}})["ok"]
        assert svc.ok("goto", down)["accepted"]
    finally:
        workers.close()
        svc.close()


def test_quick_raise_and_return_in_thread_mode(svc):
    ok, r = svc.call("hitch/raise")
    assert not ok and r["error"] == "not_found" and "no implement is selected" in r["message"]
    svc.ok("implements/define", HARROW)
    svc.ok("implements/select", {"name": "harrow"})
    ok, r = svc.call("hitch/raise")
    assert not ok and r["error"] == "not_found" and HEADLAND_PRESET in r["message"]
    ok, r = svc.call("hitch/return")
    assert not ok and r["error"] == "not_found" and "no work pose" in r["message"]
    svc.ok("presets/save", {"name": HEADLAND_PRESET, "pose": HEADLAND})  # the headland is the preset
    svc.ok("goto", {"goal": {"x": WORK["x"], "z": WORK["z"]}})
    svc.run(5.0)
    work = svc.pose().copy()  # the pose the raise starts from (roll and pitch as the goto kept them)
    r = svc.ok("hitch/raise")
    assert r["accepted"] and [r["last_work"][k] for k in ("x", "z", "roll", "pitch")] == pytest.approx(work)
    svc.run(r["duration"] + 0.3)
    np.testing.assert_allclose(svc.pose(), [HEADLAND[k] for k in ("x", "z", "roll", "pitch")], atol=1e-6)
    svc.ok("hitch/raise")  # again at the headland: the work pose is kept
    svc.run(0.5)
    r = svc.ok("hitch/return")
    assert r["accepted"]
    svc.run(r["duration"] + 0.3)
    np.testing.assert_allclose(svc.pose(), work, atol=1e-6)
    # the implement's own headland pose takes precedence over the preset
    svc.ok("implements/define", {**HARROW, "headland": {**HEADLAND, "z": 0.2}})
    r = svc.ok("hitch/raise")
    svc.run(r["duration"] + 0.3)
    assert svc.pose()[1] == pytest.approx(0.2, abs=1e-6)


def test_a_recorded_work_pose_is_announced_once_stored(svc):
    """A raise from the cab's switch or another client changed the last work pose without a word (the terminal's
    Implement tab kept the old one: an audit). ``last_work_recorded`` says it, after it is stored; a raise that
    keeps the pose says nothing."""
    seen: list[tuple[dict, dict]] = []  # (the event, implements/list's record asked on it)

    def on_event(event: dict) -> None:
        if event.get("event") == "last_work_recorded":
            (rec,) = [i for i in svc.ok("implements/list")["implements"] if i["name"] == event["implement"]]
            seen.append((event, rec))

    svc.ok("implements/define", {**HARROW, "headland": HEADLAND})
    svc.ok("implements/select", {"name": "harrow"})
    svc.ok("goto", {"goal": {"x": WORK["x"], "z": WORK["z"]}})
    svc.run(5.0)
    svc.event_listeners.append(on_event)
    r = svc.ok("hitch/raise")
    assert len(seen) == 1, seen
    event, rec = seen[0]
    assert event["implement"] == "harrow" and event["last_work"] == r["last_work"] == rec["last_work"], seen
    svc.run(r["duration"] + 0.3)
    r = svc.ok("hitch/raise")  # at the headland: the work pose is kept, nothing is announced
    assert r.get("last_work_kept") is True and len(seen) == 1, (r, seen)


def test_a_return_after_a_raise_that_started_at_the_headland_says_that_raise_recorded_no_work_pose(svc):
    """A new user's report: raised at the headland pose, `hitch return` said "has no work pose yet (raise it
    once first)" — they just had. A raise from the headland pose keeps (here: has) no work pose; say so."""
    svc.ok("implements/define", {**HARROW, "headland": HEADLAND})
    svc.ok("implements/select", {"name": "harrow"})
    svc.ok("goto", {"goal": HEADLAND})
    svc.run(5.0)
    r = svc.ok("hitch/raise")  # accepted: already at the headland pose, so no work pose is recorded
    svc.run(r["duration"] + 0.3)
    ok, r = svc.call("hitch/return")
    assert not ok and r["error"] == "not_found"
    msg = r["message"]
    assert "raise it once first" not in msg
    assert "no work pose yet" in msg and "starts at the headland pose (within 5 mm / 5 mrad" in msg
    assert "raise from a work pose first" in msg


def test_a_refused_quick_raise_is_called_a_raise(svc):
    """A field operator's report: `hitch raise` with a fault held answered "hitch/raise: preset refused: …"."""
    from bridge.service.motion.types import Fault

    svc.ok("implements/define", HARROW)
    svc.ok("implements/select", {"name": "harrow"})
    svc.ok("presets/save", {"name": HEADLAND_PRESET, "pose": HEADLAND})
    svc.mc._faults.hold(Fault("internal", "a test's fault", True, 0.0))
    ok, r = svc.call("hitch/raise")
    assert not ok and r["error"] == "ecu" and "raise refused: fault held: internal" in r["message"], r
    assert "preset" not in r["message"], r


def test_a_redefinition_names_the_fields_it_cleared(svc):
    """A define replaces the whole record: a newcomer changed the mass only and lost the upper height, the
    lowering speed and the headland pose without a word. The reply names them (``cleared``); kept fields not."""
    full = {**HARROW, "upper_height_m": 0.28, "lowering_speed_m_s": 0.05, "headland": HEADLAND, "description": "d"}
    assert svc.ok("implements/define", full)["cleared"] == []  # new
    assert svc.ok("implements/define", full)["cleared"] == []  # the same again
    r = svc.ok("implements/define", {**HARROW, "mass_kg": 1100.0})
    assert r["cleared"] == ["upper_height_m", "lowering_speed_m_s", "headland", "description"], r
    imp = r["implement"]
    assert imp["upper_height_m"] is None and imp["headland"] is None and imp["mass_kg"] == 1100.0, imp
    assert svc.ok("implements/define", {**HARROW, "upper_height_m": 0.3})["cleared"] == []  # nothing left to clear


def test_a_headland_preset_that_the_implement_s_own_pose_shadows_is_said_so(svc):
    """A newcomer taught ``hitch preset save headland`` for an implement defined with a headland pose: saved, and
    every raise still went to the implement's pose. The reply's ``note`` says so; without one, no note."""
    svc.ok("implements/define", {**HARROW, "headland": HEADLAND})
    svc.ok("implements/select", {"name": "harrow"})
    r = svc.ok("presets/save", {"name": HEADLAND_PRESET})
    assert "has a headland pose of its own" in r["note"] and "hitch/raise goes there" in r["note"], r
    assert "note" not in svc.ok("presets/save", {"name": "work"})  # another name: nothing to say
    svc.ok("implements/define", HARROW)  # without a headland pose: the preset is the one a raise goes to
    assert "note" not in svc.ok("presets/save", {"name": HEADLAND_PRESET, "replace": True})


def test_a_raise_refused_by_the_mode_or_the_lock_is_called_a_raise(svc):
    """A newcomer's trial: ``hitch raise`` in transport mode answered "hitch/raise: preset is refused in mode
    'transport'", and with the lock on "preset refused: the implement is transport-locked"."""
    svc.ok("implements/define", {**HARROW, "headland": HEADLAND})
    svc.ok("implements/select", {"name": "harrow"})
    svc.ok("mode", {"mode": "transport"})
    ok, r = svc.call("hitch/raise")
    assert not ok and r["error"] == "mode" and "raise is refused in mode 'transport'" in r["message"], r
    assert "preset" not in r["message"], r
    svc.ok("mode", {"mode": "auto"})
    svc.ok("implements/lock")
    ok, r = svc.call("hitch/raise")
    assert not ok and r["error"] == "locked" and "raise refused: the implement is transport-locked" in r["message"], r
    assert "preset" not in r["message"], r


@pytest.mark.slow
def test_quick_raise_return_and_selection_with_the_core_in_its_own_process(tmp_path):
    cfg = ServiceConfig(listen=[f"tcp/127.0.0.1:{free_port()}"], data_dir=tmp_path, planning_processes=0)
    svc = HitchService(cfg).start()
    try:
        assert svc.core is not None  # the default: the core has its own process

        def call(key, payload=None):
            ok, r = svc.api.handle(key, json.dumps(payload or {}))
            assert ok, (key, r)
            return r

        def z_now():
            return ((svc.latest_state or {}).get("pose") or {}).get("z")

        assert wait_until(lambda: z_now() is not None), "no state from the core"
        # a pose is reported from the first measurement, before the link is up (heartbeats in sequence): a goto
        # sent then is refused `ecu`, not by the guard (a CI-style run, 2026-12-06); wait as a client would
        assert wait_until(lambda: ((svc.latest_state or {}).get("ecu") or {}).get("online") is True), "ECU not online"
        call("implements/define", {**HARROW, "headland": HEADLAND, "upper_height_m": 0.28})
        call("implements/select", {"name": "harrow"})
        ok, r = svc.api.handle("goto", json.dumps({"goal": {"z": 0.3}}))
        assert not ok and r["error"] == "refused" and UPPER_HEIGHT_LIMIT in r["message"]  # the core's guard has it
        call("goto", {"goal": {"z": WORK["z"], "x": WORK["x"]}})
        assert wait_until(lambda: abs(z_now() - WORK["z"]) < 3e-3)
        assert wait_until(lambda: call("hitch/raise")["accepted"] if svc.latest_state["motion"] is None else False)
        assert wait_until(lambda: abs(z_now() - HEADLAND["z"]) < 3e-3 and svc.latest_state["motion"] is None)
        call("implements/lock")
        ok, r = svc.api.handle("hitch/return", "{}")
        assert not ok and r["error"] == "locked"
        call("implements/unlock")
        call("hitch/return")
        assert wait_until(lambda: abs(z_now() - WORK["z"]) < 3e-3)
    finally:
        svc.close()


@pytest.mark.slow
def test_the_cli_round_trip_against_a_running_service(tmp_path, capsys):
    """``hitch implement define|list|select|lock|unlock``, ``hitch raise|return --wait`` and ``hitch switch
    --service`` against a service with the core in its own process (the default)."""
    from bridge.cli.main import main

    ep = f"tcp/127.0.0.1:{free_port()}"
    svc = HitchService(ServiceConfig(listen=[ep], data_dir=tmp_path, planning_processes=0)).start()

    def cli(*argv: str) -> tuple[int, str, str]:
        rc = main([*argv, "--connect", ep, "--timeout", "20"])
        out = capsys.readouterr()
        return rc, out.out, out.err

    def z_now():
        return ((svc.latest_state or {}).get("pose") or {}).get("z")

    try:
        assert wait_until(lambda: (svc.latest_state or {}).get("ecu", {}).get("online")), "no state from the core"
        rc, out, err = cli(
            "implement", "define", "harrow", "--category", "2", "--mass", "800", "--com", "0,0.6,0.3",
            "--upper-height", "0.28", "--lowering-speed", "0.2", "--headland", "x=0,z=0.24,roll=0,pitch=0",
        )  # fmt: skip
        assert rc == 0 and "defined harrow" in out, err
        rc, out, err = cli("implement", "define", "bad", "--category", "7", "--mass", "800", "--com", "0,0,0")
        assert rc != 0 and "category" in err, err
        rc, out, err = cli("implement", "select", "harrow")
        assert rc == 0 and "selected harrow" in out, err
        rc, out, _ = cli("implement", "list")
        assert rc == 0 and "* harrow (cat 2, 800 kg" in out and "upper 0.28 m, lowering 0.2 m/s" in out, out
        rc, out, _ = cli("implement", "list", "--json")
        assert rc == 0 and json.loads(out)["selected"] == "harrow"
        rc, out, err = cli("implement", "lock")
        assert rc == 0 and "transport lock on" in out, err
        rc, out, err = cli("raise")
        assert rc != 0 and "locked" in err, err
        rc, out, err = cli("implement", "unlock")
        assert rc == 0 and "transport lock off" in out, err
        assert wait_until(lambda: svc.api.handle("goto", json.dumps({"goal": {"z": WORK["z"]}}))[0])
        assert wait_until(lambda: abs(z_now() - WORK["z"]) < 3e-3 and svc.latest_state["motion"] is None)
        rc, out, err = cli("raise", "--wait")
        assert rc == 0 and "raise to" in out and abs(z_now() - 0.24) < 3e-3, (out, err)
        rc, out, err = cli("return", "--wait")
        assert rc == 0 and "return to" in out and abs(z_now() - WORK["z"]) < 3e-3, (out, err)
        rc, out, err = cli("switch", "raise", "--service")
        assert rc == 0 and "released, raise, released" in out, err
        assert wait_until(lambda: abs(z_now() - 0.24) < 3e-3 and svc.latest_state["motion"] is None)
    finally:
        svc.close()


def test_an_implement_mass_in_tonnes_is_refused_with_the_tonnes_reading(svc):
    """A user trial: ``hitch implement define x --category 3 --mass 1.2`` defined a 1.2 kg implement. The range is
    the tractor profile's records' one, (20, 20000] kg, and a mass in tonnes is named as the tractor's is."""
    ok, r = svc.call("implements/define", {**HARROW, "name": "plough", "mass_kg": 1.2})
    assert not ok and r["error"] == "bad_request", r
    assert r["message"] == (
        "implements/define: mass_kg = 1.2 is out of range (allowed: > 20 and <= 20000 kg); did you mean t? 1.2 t = "
        "1200 kg"
    ), r
    assert "plough" not in [i["name"] for i in svc.ok("implements/list")["implements"]]
    ok, r = svc.call("implements/define", {**HARROW, "name": "plough", "mass_kg": 25_000.0})  # 25 t: no hint
    assert not ok and r["message"].endswith("(allowed: > 20 and <= 20000 kg)"), r
    assert svc.ok("implements/define", {**HARROW, "name": "plough", "mass_kg": 20.5})["defined"] == "plough"


@pytest.mark.parametrize(
    "key, payload, code, text",
    [
        # each message once headed by its key, saying what is wrong (as new users read the old ones:
        # "track/start: payload = a JSON object dof: …", "track/stop: session None is not live",
        # "no implement 'nope' …" without its key, a script name mismatch as a 500 "store" error)
        ("track/start", {"dof": ["z", "z"]}, "bad_request", "track/start: dof: each of x, z, roll, pitch at most once"),
        ("track/stop", {}, "not_found", "track/stop: no track session is live (track/start starts one)"),
        ("implements/select", {"name": "nope"}, "not_found", "implements/select: no implement 'nope'"),
        ("lines/delete", {"name": "zz"}, "not_found", "lines/delete: no line 'zz'"),
        (
            "maneuvers/save",
            {"name": "a", "script": "name: b\nsteps:\n  - wait: 1\n"},
            "bad_request",
            "maneuvers/save: name: the script calls itself 'b' but is saved as 'a'",
        ),
        (  # saved, then every run refused it, while presets/save refused the same pose (a fleet trial)
            "maneuvers/save",
            {"name": "high", "script": "steps:\n  - wait: 1\n  - goto: {x: 0, z: 0.9}\n"},
            "unreachable",
            "maneuvers/save: step 2 (index 1, goto): goal.z = 0.9000 m is above the workspace (workspace:z:max = ",
        ),
    ],
)
def test_refusals_name_their_key_once_and_the_right_code(svc, key, payload, code, text):
    ok, r = svc.call(key, payload)
    assert not ok and r["error"] == code and r["message"].startswith(text), r
    assert not r["message"].startswith(f"{key}: {key}")


def test_an_implement_limit_the_hitch_can_never_meet_is_refused(svc, model):
    """The old service took upper_height_m = -0.9 m (below the workspace floor: every motion up refused, a
    track session pulled the hitch down) and mass_kg = 1e-300."""
    from planner.trajectory import TrajectoryPlanner

    tp = TrajectoryPlanner(model)  # the service's config carries its workspace (machine.service_info)
    svc.api.info["limits"] = {"workspace": {k: list(tp.workspace[k]) for k in ("x", "z", "roll", "pitch")}}
    z_min = float(tp.workspace["z"][0])
    ok, r = svc.call("implements/define", {**HARROW, "name": "low", "upper_height_m": -0.9})
    assert not ok and r["error"] == "bad_request", r
    assert (
        "upper_height_m = -0.9 m is below the workspace's lowest z" in r["message"] and f"{z_min:.4g}" in r["message"]
    )
    ok, r = svc.call("implements/define", {**HARROW, "name": "feather", "mass_kg": 1e-300})
    assert not ok and "mass_kg" in r["message"] and "> 20" in r["message"], r
    assert svc.ok("implements/define", {**HARROW, "name": "fine", "upper_height_m": z_min + 0.1})["defined"] == "fine"
