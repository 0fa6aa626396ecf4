"""Planning workers (``bridge.service.workers``): the same answers as planning in the service's own
threads, nothing run after its timeout, a dead or hung worker replaced, and a program that embeds
the service needs no ``__main__`` guard.

Truth: :class:`~bridge.service.planning.InProcessPlanning` on a guard and IK solver of the same
profile (the code path the service used before), compared reply by reply through
:class:`~bridge.service.api.ServiceAPI`.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from bridge.link.count_tail import plan_count_tail
from bridge.link.reference_check import ReferenceCheck
from bridge.service.api import ServiceAPI
from bridge.service.maneuvers.language import guarded_plan_step, parse_maneuver
from bridge.service.store import HitchStore
from bridge.service.workers import (
    PlanningWorkers,
    PresetPose,
    WorkerError,
    WorkerSpec,
    check_spec,
    referenced_presets,
)
from planner.errors import HitchInputError
from planner.ik_qp.hitch_ik import IKSolver
from planner.limits.guard import Guard
from planner.model.kinematics import HitchModel
from planner.trajectory import MotionState, TrajectoryPlanner

SPEC = WorkerSpec("thesis-t132", None, 50.0, None)


@pytest.fixture(scope="module")
def workers():
    w = PlanningWorkers(SPEC, processes=1).start()
    w.warm(60.0)
    yield w
    w.close()


class _Motion:
    """What the API's planning requests read of the controller: the start state and the planning guard."""

    mode = "auto"

    def __init__(self, model: HitchModel):
        self.guard = Guard(TrajectoryPlanner(model, rate=50.0))
        self.planner = self.guard.planner
        self.plan_step = guarded_plan_step(self.guard)
        self.start = MotionState.at_rest(model.neutral_pose.controlled())

    def clock(self) -> float:
        return 0.0

    def preview_start(self) -> MotionState:
        return self.start

    def current_state(self) -> MotionState:
        return self.start

    def preview_from(self, start, goal, speed_scale=1.0):
        return self.guard.plan(start, goal, speed_scale=speed_scale)

    def preview_with_tail(self, start, goal, speed_scale=1.0):
        gp = self.preview_from(start, goal, speed_scale)
        return gp, plan_count_tail(self.planner, gp.plan, ReferenceCheck(self.planner.model), self.guard)


@pytest.fixture(scope="module")
def apis(workers, tmp_path_factory):
    model = HitchModel.from_profile("thesis-t132")
    motion = _Motion(model)
    store = HitchStore(tmp_path_factory.mktemp("w") / "h.sqlite3")
    store.save_preset("work", {"x": 0.0, "z": 0.2, "roll": 0.0, "pitch": 0.0})
    info = {"profile": "thesis-t132"}
    local = ServiceAPI(motion, IKSolver(HitchModel.from_profile("thesis-t132")), store, info)  # type: ignore[arg-type]
    remote = ServiceAPI(motion, None, store, info, planning=workers)  # type: ignore[arg-type]
    yield local, remote
    store.close()


def _drop_times(reply: dict) -> dict:
    return {k: v for k, v in reply.items() if k != "solve_time_s"}


def _random_goals(n: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        out.append(
            {
                "x": float(rng.uniform(-0.06, 0.06)),
                "z": float(rng.uniform(0.0, 0.45)),
                "roll": float(rng.uniform(-0.1, 0.1)),
                "pitch": float(rng.uniform(-0.2, 0.2)),
            }
        )
    return out


def test_plan_previews_are_identical_to_planning_in_the_service_threads(apis):
    local, remote = apis
    goals = _random_goals(8, seed=3) + [{"z": 5.0}, {"x": 1.9}, {"z": 0.3, "roll": 0.5}]  # some refused or invalid
    for goal in goals:
        for scale in (1.0, 0.3):
            body = json.dumps({"goal": goal, "speed_scale": scale})
            a, b = local.handle("plan", body), remote.handle("plan", body)
            assert a == b, (goal, scale)
    assert any(ok and r["ok"] for ok, r in (local.handle("plan", json.dumps({"goal": g})) for g in goals))


def test_ik_answers_are_identical_including_failures(apis):
    local, remote = apis
    for g in _random_goals(5, seed=4) + [{"x": 0.0, "z": 1.5, "roll": 0.0, "pitch": 0.0}]:
        body = json.dumps(g)
        (oka, a), (okb, b) = local.handle("ik", body), remote.handle("ik", body)
        assert oka == okb and _drop_times(a) == _drop_times(b), g
        if not oka:
            assert a["error"] == "ik_failed" and a["message"].startswith("ik: no solution"), a


def test_maneuver_validation_is_identical_with_presets_and_errors(apis):
    local, remote = apis
    scripts = [
        "steps: [{goto: {z: 0.3}}, {wait: 1}, {preset: work}, {speed: 0.5}, {goto: {x: 0.03, pitch: 0.03}}]",
        "steps: [{preset: nowhere}, {goto: {z: 0.3}}]",
        "steps: [{goto: {z: 3.0}}]",
        "steps: [{goto: {zz: 0.3}}]",
        "not: a maneuver",
    ]
    for script in scripts:
        body = json.dumps({"script": script})
        assert local.handle("maneuvers/validate", body) == remote.handle("maneuvers/validate", body), script
    ok, reply = remote.handle("maneuvers/validate", json.dumps({"script": scripts[0]}))
    assert ok and reply["ok"] and reply["duration"] > 1.0, reply


def test_referenced_presets_lists_each_name_once_in_order():
    script = parse_maneuver("steps: [{preset: b}, {goto: {z: 0.3}}, {preset: a}, {preset: b}]")
    assert referenced_presets(script) == ("b", "a")


def test_a_task_past_its_timeout_is_abandoned_and_its_worker_replaced(workers):
    start = MotionState.at_rest(HitchModel.from_profile("thesis-t132").neutral_pose.controlled())
    before = workers.replaced
    old = set(workers.pids)
    with pytest.raises(WorkerError) as e:
        workers.call("preview", start, {"z": 0.3, "pitch": 0.05}, 0.05, timeout_s=1e-4)  # a plan takes ms
    assert e.value.code == "busy" and "not run later" in str(e.value)
    assert workers.replaced == before + 1 and not (set(workers.pids) & old)  # the old process is gone
    reply = workers.preview(start, {"z": 0.3}, 1.0)  # the new one answers
    assert reply["ok"] and reply["duration"] > 0


def test_a_worker_that_died_is_replaced_and_the_caller_told(workers):
    (pid,) = workers.pids
    os.kill(pid, signal.SIGKILL)
    time.sleep(0.2)
    with pytest.raises(WorkerError) as e:
        workers.ik((0.0, 0.25, 0.0, 0.0))
    assert e.value.code == "internal" and "restarted" in str(e.value)
    assert workers.ik((0.0, 0.25, 0.0, 0.0))["status"] != "failed"


def test_no_idle_worker_within_the_timeout_is_busy_at_once(workers):
    held = workers._idle.get(timeout=30.0)  # another caller's task occupies the only worker
    try:
        t0 = time.monotonic()
        with pytest.raises(WorkerError) as e:
            workers.call("ping", timeout_s=0.2)
        assert e.value.code == "busy" and "stayed busy" in str(e.value)
        assert time.monotonic() - t0 < 5.0
    finally:
        workers._idle.put(held)


def test_bad_arguments_and_closed_workers_are_errors_not_crashes():
    w = PlanningWorkers(SPEC, processes=1)
    with pytest.raises(ValueError, match="1..32"):
        PlanningWorkers(SPEC, processes=0)
    with pytest.raises(WorkerError, match="positive"):
        w.call("ping", timeout_s=float("nan"))
    w.start()
    pids = w.pids
    w.close()
    with pytest.raises(WorkerError) as e:
        w.call("ping")
    assert e.value.code == "unavailable"
    for pid in pids:  # terminated, not left running
        with pytest.raises(ProcessLookupError):
            for _ in range(50):
                os.kill(pid, 0)
                time.sleep(0.05)


def test_a_script_without_a_main_guard_can_start_workers(tmp_path):
    # a multiprocessing "spawn" worker re-imports the parent's main file; that file starting
    # workers at import time fails ("An attempt has been made to start a new process …")
    script = tmp_path / "embed.py"
    script.write_text(
        textwrap.dedent(
            """
            from bridge.service.workers import PlanningWorkers, WorkerSpec
            w = PlanningWorkers(WorkerSpec("thesis-t132", None, 50.0, None), processes=1).start()
            print(w.ik((0.0, 0.25, 0.0, 0.0))["status"])
            w.close()
            """
        )
    )
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "ok", out.stdout
    assert "bootstrapping phase" not in out.stderr


def test_preset_pose_is_plain_data():
    p = PresetPose({"z": 0.2}, 0.5)
    assert p.pose["z"] == 0.2 and p.speed_scale == 0.5


def test_a_spec_that_does_not_exist_is_refused_before_any_worker_starts():
    for spec, message in [
        (WorkerSpec("nosuch", None, 50.0, None), "profile 'nosuch' not found; built-in profiles: thesis-t132"),
        (WorkerSpec("thesis-t132", "9", 50.0, None), "category '9' is not in profile 'thesis-t132'; allowed: 1N"),
        (WorkerSpec("thesis-t132", None, 50.0, "nosuch"), "implement 'nosuch' is not in tractor profile"),
    ]:
        w = PlanningWorkers(spec, processes=2)
        with pytest.raises(HitchInputError) as e:
            w.start()
        assert message in str(e.value)
        assert w.pids == ()  # nothing spawned
        w.close()
    check_spec(SPEC)  # a spec that builds passes
    check_spec(WorkerSpec("thesis-t132", "2", 50.0, "cat2-spreader-400"))


def test_a_worker_that_cannot_build_its_context_tells_every_caller_and_prints_no_traceback(capfd):
    w = PlanningWorkers(WorkerSpec("nosuch", None, 50.0, None), processes=1)
    w._idle.put(w._spawn())  # past check_spec (e.g. a profile file removed meanwhile): the worker meets the error
    try:
        with pytest.raises(WorkerError) as e:
            w.warm(60.0)
        assert e.value.code == "unavailable"
        assert "the planning process could not start: ProfileError: profile 'nosuch' not found" in str(e.value)
        with pytest.raises(WorkerError) as e:  # every later task too, from the same (live) process
            w.ik((0.0, 0.25, 0.0, 0.0))
        assert e.value.code == "unavailable" and "could not start" in str(e.value)
        assert w.replaced == 0
    finally:
        w.close()
    assert "Traceback" not in capfd.readouterr().err
