"""A goto whose planning takes longer than the motion controller's switch lead (a long, slow plan
on a loaded 2-core machine: 0.25 s in-process for a 15 s plan, 0.4–0.8 s measured inside a busy
``hitch serve``) still starts: from rest at once when ready, while moving from a lead sized by the
time planning took. Simulated time: the rig runs on while the planner "thinks"."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.service.motion.controller import MotionController
from bridge.service.motion.types import plan_state
from bridge.sim.move import SimRig
from planner.limits.guard import Guard
from planner.model.exact_inverse import ExactInverse
from planner.trajectory import TrajectoryPlanner

PLAN_S = 0.7  # simulated planning time, longer than 0.08 + 0.16 + 0.32 + 0.64 s of doubling leads


class SlowGuard(Guard):
    """A planning guard whose plans take ``PLAN_S`` of the rig's time (the world goes on meanwhile)."""

    def __init__(self, planner, rig):
        super().__init__(planner)
        self.rig, self.calls, self.during_first = rig, 0, None

    def plan(self, *args, **kwargs):
        self.calls += 1
        if self.calls == 1 and self.during_first is not None:
            self.during_first()
        self.rig.run_until(self.rig.now_s + PLAN_S)
        return super().plan(*args, **kwargs)


@pytest.fixture
def setup(model):
    rig = SimRig(model)
    rig.start()
    rig.run_until(0.5)
    events: list[dict] = []
    slow = SlowGuard(TrajectoryPlanner(model), rig)
    mc = MotionController(
        Guard(TrajectoryPlanner(model)),
        slow,
        rig.link,
        lambda: rig.now_s,
        on_event=events.append,
        spawn=lambda fn: fn(),
    )
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
    assert slow.calls == 1  # planned once: no retry from rest
    started = [e for e in events if e["event"] == "motion_started"]
    assert started and started[0]["motion_id"] == acc.motion_id
    assert rig.now_s - t_request == pytest.approx(PLAN_S, abs=1e-6)
    _run(rig, mc, acc.duration + 1.0)
    assert any(e["event"] == "motion_finished" for e in events)
    assert abs(mc.current_state().position[1] - 0.2) < 1e-9


def test_a_slow_plan_replacing_a_motion_starts_on_a_longer_lead(setup):
    rig, mc, slow, events = setup
    first = mc.goto({"z": 0.25}, speed_scale=0.5)
    _run(rig, mc, 1.0)  # moving now
    assert mc.current_state().moving
    second = mc.goto({"z": -0.1}, speed_scale=0.5)
    # 0.08 s lead was too short; the next one is 1.5 × 0.7 + 0.02 = 1.07 s: accepted on the second try
    assert slow.calls == 3 and second.motion_id > first.motion_id
    # the switch is smooth: the new plan starts from the replaced one's exact state at the switch time
    pm = mc._active
    old, new = plan_state(pm.prev, pm.t0), pm.plan.state_at(0.0)
    for a, b in ((old.position, new.position), (old.velocity, new.velocity), (old.acceleration, new.acceleration)):
        np.testing.assert_allclose(a, b, atol=1e-9)
    assert np.linalg.norm(old.velocity) > 0.01  # it was switched while moving
    names = [e["event"] for e in events]
    assert names.count("motion_started") == 2 and "motion_aborted" in names
    _run(rig, mc, second.duration + 2.0)
    assert abs(mc.current_state().position[1] + 0.1) < 1e-9


def test_a_measured_start_that_moved_while_planning_is_planned_again(setup, model):
    """No motion held (fresh controller): the start is the measured pose. If the pistons move
    meanwhile (here: a reference streamed by someone else during the first planning), the plan
    is made again from where they are, instead of stepping back to the old pose."""
    rig, mc, slow, events = setup
    assert mc._hold is None and mc._active is None
    before = np.array([rig.link.latest_state().pose.z])
    q_up = ExactInverse(model)(0.0, float(before[0]) + 0.05, 0.0, 0.0)
    slow.during_first = lambda: rig.link.send_reference(q_up, rig.now_s)
    acc = mc.goto({"x": 0.02}, speed_scale=1.0)
    assert slow.calls >= 2, "the first plan's start had moved: planned again"
    start_z = mc._active.plan.state_at(0.0).position[1]
    assert abs(start_z - rig.link.latest_state().pose.z) < 5e-3 and start_z - before[0] > 0.02
    assert acc.motion_id == 1
