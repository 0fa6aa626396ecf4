"""A goto whose planning takes longer than the motion controller's switch lead (a long, slow plan
on a loaded 2-core machine: 0.25 s in-process for a 15 s plan, 0.4–0.8 s measured inside a busy
``hitch serve``) still starts: from rest at once when ready, while moving from a lead sized by the
time planning took. Simulated time: the rig runs on while the planner "thinks"."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.service.motion import MotionController
from bridge.sim_run import SimRig
from planner.limits.guard import Guard
from planner.trajectory import TrajectoryPlanner

PLAN_S = 0.7          # simulated planning time, longer than 0.08 + 0.16 + 0.32 + 0.64 s of doubling leads


class SlowGuard(Guard):
    """A planning guard whose plans take ``PLAN_S`` of the rig's time (the world goes on meanwhile)."""

    def __init__(self, planner, rig):
        super().__init__(planner)
        self.rig, self.calls = rig, 0

    def plan(self, *args, **kwargs):
        self.calls += 1
        self.rig.run_until(self.rig.now_s + PLAN_S)
        return super().plan(*args, **kwargs)


@pytest.fixture
def setup(model):
    rig = SimRig(model)
    rig.start()
    rig.run_until(0.5)
    events: list[dict] = []
    slow = SlowGuard(TrajectoryPlanner(model), rig)
    mc = MotionController(Guard(TrajectoryPlanner(model)), slow, rig.link, lambda: rig.now_s,
                          on_event=events.append, spawn=lambda fn: fn())
    mc.cycle()
    yield rig, mc, slow, events
    rig.close()


def _run(rig, mc, seconds):
    end = rig.now_s + seconds
    while rig.now_s < end - 1e-9:
        rig.run_until(rig.now_s + 0.02)
        mc.cycle()


def test_a_slow_plan_from_rest_starts_when_ready(setup):
    rig, mc, slow, events = setup
    t_request = rig.now_s
    acc = mc.goto({"z": 0.2}, speed_scale=0.3)
    assert slow.calls == 1                                   # planned once: no retry from rest
    started = [e for e in events if e["event"] == "motion_started"]
    assert started and started[0]["motion_id"] == acc.motion_id
    assert rig.now_s - t_request == pytest.approx(PLAN_S, abs=1e-6)
    _run(rig, mc, acc.duration + 1.0)
    assert any(e["event"] == "motion_finished" for e in events)
    assert abs(mc.current_state().position[1] - 0.2) < 1e-9


def test_a_slow_plan_replacing_a_motion_starts_on_a_longer_lead(setup):
    rig, mc, slow, events = setup
    first = mc.goto({"z": 0.25}, speed_scale=0.5)
    _run(rig, mc, 1.0)                                       # moving now
    assert mc.current_state().moving
    second = mc.goto({"z": -0.1}, speed_scale=0.5)
    # 0.08 s lead was too short; the next one is 1.5 × 0.7 + 0.02 = 1.07 s: accepted on the second try
    assert slow.calls == 3 and second.motion_id > first.motion_id
    names = [e["event"] for e in events]
    assert names.count("motion_started") == 2 and "motion_aborted" in names
    _run(rig, mc, second.duration + 2.0)
    assert abs(mc.current_state().position[1] + 0.1) < 1e-9
    # the switch is smooth: the replaced plan ran until the switch time
    assert np.all(np.isfinite(mc.current_state().position))
