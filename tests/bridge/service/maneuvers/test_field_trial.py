"""A field-scripting user's trial: skipping the last step while paused, saves that silently replaced a
maneuver, step numbers that differed between validate and save, and validation that stopped at the first
problem."""

from __future__ import annotations

import pytest

from bridge.service.maneuvers.runner import LoopState, ManeuverRunner
from planner.ik_qp.hitch_ik import IKSolver
from tests.bridge.service.test_maneuvers import _validated
from tests.helpers import SimService


class _Svc(SimService):
    def __init__(self, model, tmp_path):
        super().__init__(model, tmp_path / "h.sqlite3", ik=IKSolver(model))


@pytest.fixture
def svc(model, tmp_path):
    s = _Svc(model, tmp_path)
    yield s
    s.close()


# ------------------------------------------------------------------------------------------ 1. skip the last step
def test_the_runner_finishes_when_the_last_step_is_skipped_while_paused():
    run = ManeuverRunner(_validated("timeout: 5\nsteps: [{wait: 1}, {goto: {z: 0.1}}]"))
    assert run.step(0.0, LoopState(False, None, 0.0)).action == "continue"
    assert run.step(1.0, LoopState(False, None, 1.0)).action == "goto"
    run.motion_started(5)
    run.pause(1.5)
    events, motion = run.skip(30.0)  # long after the timeout, which stands still while paused
    assert motion and [e["event"] for e in events] == ["maneuver_skipped", "maneuver_finished"]
    assert events[1]["elapsed"] == pytest.approx(1.5)  # the pause is not run time
    assert run.status == "finished" and not run.paused and run.current_step is None
    assert run.step(30.02, LoopState(False, 5, 30.0)).action == "done"


def test_skipping_the_last_step_while_paused_finishes_the_maneuver_at_rest(svc):
    """The trial: pause during the last goto, skip → "skip: maneuver 10 paused, step None", the maneuver paused
    for good (its timeout frozen) until resume or stop."""
    assert svc.call("maneuvers/save", {"name": "m", "script": "steps:\n  - wait: 0.2\n  - goto: {z: 0.3}\n"})[0]
    ok, r = svc.call("maneuvers/run", {"name": "m"})
    assert ok, r
    mid = r["maneuver_id"]
    svc.run(0.8)
    ok, r = svc.call("maneuvers/pause")
    assert ok and r["maneuver"]["step"] == 1 and r["maneuver"]["paused"] is True, r
    svc.run(1.5)
    ok, r = svc.call("maneuvers/skip")
    assert ok and r["maneuver"] is None and r["maneuver_id"] == mid, r
    svc.run(0.5)
    assert svc.states[-1]["maneuver"] is None and not svc.states[-1]["moving"]
    names = [e["event"] for e in svc.events if e.get("maneuver_id") == mid]
    assert names[-2:] == ["maneuver_skipped", "maneuver_finished"], names
    held = svc.states[-1]["pose"]["z"]
    svc.run(1.0)
    assert abs(svc.states[-1]["pose"]["z"] - held) < 2e-3 and held < 0.28  # at rest where the pause left it
    assert not svc.call("maneuvers/resume")[0]  # nothing runs any more


# ------------------------------------------------------------------------------------------ 2. no silent replace
SIX = "steps:\n  - wait: 1\n  - wait: 1\n  - wait: 1\n  - wait: 1\n  - wait: 1\n  - wait: 1\n"


def test_save_refuses_a_name_saved_already_unless_replace(svc):
    assert svc.call("maneuvers/save", {"name": "lift", "script": SIX}) == (True, {"saved": "lift", "steps": 6})
    ok, r = svc.call("maneuvers/save", {"name": "lift", "script": "steps: [{wait: 2}]"})
    assert not ok and r["error"] == "in_use", r
    assert "'lift' is saved already (6 steps)" in r["message"] and '"replace": true' in r["message"], r
    assert "--replace" in r["message"]
    assert len(svc.api.store.get_maneuver("lift").parsed.steps) == 6  # untouched
    ok, r = svc.call("maneuvers/save", {"name": "lift", "script": "steps: [{wait: 2}]", "replace": True})
    assert ok and r == {"saved": "lift", "steps": 1, "replaced": True}, r
    ok, r = svc.call("maneuvers/save", {"name": "new", "script": "steps: [{wait: 2}]", "replace": True})
    assert ok and r == {"saved": "new", "steps": 1}, r  # replace where nothing is saved: a plain save


def test_record_stop_with_a_saved_name_keeps_the_recording(svc):
    assert svc.call("maneuvers/save", {"name": "lift", "script": SIX})[0]
    assert svc.call("maneuvers/record/start")[0]
    ok, r = svc.call("goto", {"goal": {"z": 0.1}})
    assert ok, r
    svc.run(r["duration"] + 0.5)
    ok, r = svc.call("maneuvers/record/stop", {"name": "lift"})
    assert not ok and r["error"] == "in_use", r
    assert "'lift' is saved already (6 steps)" in r["message"] and "the recording goes on" in r["message"], r
    assert len(svc.api.store.get_maneuver("lift").parsed.steps) == 6
    assert svc.api.recorder is not None  # still recording: nothing taught is lost
    ok, r = svc.call("maneuvers/record/stop", {"name": "lift2"})
    assert ok and r["saved"] == "lift2" and r["steps"] == 1, r
    # and once more with replace
    assert svc.call("maneuvers/record/start")[0]
    ok, r = svc.call("goto", {"goal": {"z": 0.0}})
    svc.run(r["duration"] + 0.5)
    ok, r = svc.call("maneuvers/record/stop", {"name": "lift", "replace": True})
    assert ok and r["saved"] == "lift" and r["replaced"] is True and svc.api.recorder is None, r
    assert len(svc.api.store.get_maneuver("lift").parsed.steps) == 1


# ------------------------------------------------------------------------------------------ 3. the same step numbers
def test_save_names_the_step_in_validates_words(svc):
    """validate said ``step 1: goto cannot be planned: goal.x = 0.2000 m is left of the workspace …``, save said
    ``step 2 (goto): x = 0.2000 m …``: every text names a step as :func:`step_words` does (counted from 1, the
    0-based index of ``step`` fields beside it)."""
    script = "steps:\n  - wait: 1\n  - goto: {x: 0.2}\n"
    ok, v = svc.call("maneuvers/validate", {"script": script})
    assert ok and not v["ok"] and v["errors"][0]["step"] == 1, v
    ok, r = svc.call("maneuvers/save", {"name": "m", "script": script})
    assert not ok and r["error"] == "unreachable", r
    said = v["errors"][0]["message"].removeprefix("goto cannot be planned: ")
    assert r["message"] == f"maneuvers/save: step 2 (index 1, goto): {said}; no run could reach it", (r, v)


def test_save_gives_the_unit_hint_validate_gives(svc):
    lo, hi = svc.api.motion.planner.lo, svc.api.motion.planner.hi
    degrees = next(d for d in (1.0, 2.0, 3.0) if lo[3] <= d * 3.141592653589793 / 180 <= hi[3] and d > hi[3])
    script = f"steps:\n  - wait: 1\n  - goto: {{pitch: {degrees}}}\n"
    ok, v = svc.call("maneuvers/validate", {"script": script})
    assert ok and "did you mean degrees?" in v["errors"][0]["message"], v
    ok, r = svc.call("maneuvers/save", {"name": "m", "script": script})
    assert not ok and r["message"].startswith("maneuvers/save: step 2 (index 1, goto): goal.pitch"), r
    assert f"did you mean degrees? {degrees:g} deg = " in r["message"], r


# ------------------------------------------------------------------------------------------ 4. every problem
def test_validate_reports_every_missing_reference_and_each_steps_own_workspace_problem(svc):
    script = "steps:\n  - wait_for: {line: nosuchline, complete: true}\n  - speed: 0.5\n  - preset: nosuchpreset\n"
    ok, r = svc.call("maneuvers/validate", {"script": script})
    assert ok and not r["ok"], r
    assert [e["step"] for e in r["errors"]] == [0, 2], r
    assert "no line 'nosuchline' is saved" in r["errors"][0]["message"]
    assert "preset 'nosuchpreset' does not exist" in r["errors"][1]["message"]
    # two gotos outside the workspace, the second after one that cannot be planned: both said
    script = "steps:\n  - goto: {x: 0.2}\n  - wait: 1\n  - goto: {z: 1.5}\n  - preset: nope\n  - goto: {x: -0.3}\n"
    ok, r = svc.call("maneuvers/validate", {"script": script})
    assert ok and not r["ok"], r
    assert [e["step"] for e in r["errors"]] == [0, 2, 3, 4], r
    for i in (0, 2, 4):
        m = next(e["message"] for e in r["errors"] if e["step"] == i)
        assert m.startswith("goto cannot be planned: goal.") and "workspace" in m, r
