"""A goto ends with the profile's count approach in the product path: the service's control cycle streams
the via counts, then the final ones, and holds those; the twin's ECU then leaves every piston where the
approach expects it inside its count (the offsets measured on the twin itself).

Truth used: the twin's true pistons (simulation truth), the link's 0xFF21 references as the ECU received
them, the plan's own duration.
"""

from __future__ import annotations

import numpy as np
import pytest

from bridge.link.count_tail import build_count_tail, plan_count_tail
from bridge.link.state import ReferenceRefused
from bridge.service.motion.controller import MotionController
from bridge.sim.accuracy_run import measure_stop_offsets, visit_poses
from bridge.sim.move import SimRig
from planner.calibration.design import candidate_poses
from planner.calibration.parametric import ParametricModel
from planner.limits.guard import Guard
from planner.limits.implement_limits import ImplementLimits
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.profiles import profile_from_dict
from planner.trajectory import MotionState, TrajectoryPlanner

GOAL = {"x": 0.021, "z": 0.0537, "roll": 0.0123, "pitch": -0.0171}
POSE = ("x", "z", "roll", "pitch")


@pytest.fixture(scope="module")
def offsets(model):
    """The twin's stop offsets, measured at poses other than the goal's."""
    poses = candidate_poses(ParametricModel(model.profile), 4, random_only=True, seed=11)[0]
    return measure_stop_offsets(model, poses)


def _with_approach(model: HitchModel, offsets, final_approach: dict | None = None) -> HitchModel:
    data = model.profile.model_dump()
    data["motion"]["count_approach"] = offsets.table()
    data["motion"]["final_approach"] = final_approach
    return HitchModel(profile_from_dict(data))


def _controller(model: HitchModel, rig: SimRig, events: list[dict]) -> MotionController:
    """The service's motion controller on ``rig``'s link in simulated time, one cycle run (its state taken)."""
    mc = MotionController(
        Guard(TrajectoryPlanner(model)),
        Guard(TrajectoryPlanner(model)),
        rig.link,
        lambda: rig.now_s,
        on_event=events.append,
        spawn=lambda fn: fn(),
    )
    mc.cycle()
    return mc


def _run(model: HitchModel, *, stop_after_plan_s: float | None = None, goal: dict | None = None):
    """A goto to GOAL through the service's controller on the twin (simulated time, cycles at 50 Hz):
    the ECU's reference counts per cycle, the events, the acceptance and the rig's pistons at the end."""
    events: list[dict] = []
    refs: list[tuple[float, tuple[int, ...]]] = []
    with SimRig(model) as rig:
        rig.start()
        rig.run_until(0.5)
        mc = _controller(model, rig, events)
        acc = mc.goto(GOAL if goal is None else goal)
        t0 = mc._active.t0  # type: ignore[union-attr]  (the plan's time 0, clock time)
        plan_s = mc._active.plan.duration  # type: ignore[union-attr]
        stopped = False
        while rig.now_s < t0 + acc.duration + 2.0 - 1e-9:
            rig.run_until(rig.now_s + 0.02)
            if stop_after_plan_s is not None and not stopped and rig.now_s >= t0 + plan_s + stop_after_plan_s:
                mc.stop()
                stopped = True
            mc.cycle()
            ref = rig.ecu.reference_counts()
            if ref is not None:
                refs.append((rig.now_s - t0, tuple(int(c) for c in ref)))
        return acc, plan_s, refs, events, rig.ecu.piston_counts(), mc


def test_the_service_streams_the_via_then_the_final_counts_and_holds_them(model, offsets):
    m = _with_approach(model, offsets)
    acc, plan_s, refs, events, pistons, mc = _run(m)
    tail = build_count_tail(
        m.profile, TrajectoryPlanner(m).inverse.solve(np.array(list(GOAL.values())))[0], lambda q: None
    )
    assert tail is not None
    a = tail.approach
    assert acc.duration == pytest.approx(plan_s + a.duration_s)
    via = tuple(int(c) for c in a.via_counts)
    final = tuple(int(c) for c in a.final_counts)
    in_via = [r for t, r in refs if plan_s + 0.1 < t < plan_s + a.via_hold_s - 0.05]
    after = [r for t, r in refs if t > plan_s + a.via_hold_s + 0.1]
    assert in_via and all(r == via for r in in_via)
    assert after and all(r == final for r in after)  # the final counts, then held (not the goal's nearest)
    finished = [e for e in events if e.get("event") == "motion_finished"]
    assert len(finished) == 1
    # every piston where the approach expects it inside its count (the twin's ECU stops repeatably)
    assert np.max(np.abs(pistons - a.stop_counts)) <= 0.06, pistons - a.stop_counts
    # nearer the exact goal than the nearest whole count, actuator by actuator
    u = a.unrounded_counts
    assert np.all(np.abs(pistons - u) <= np.abs(np.round(u) - u) + 0.06)
    assert np.sum(np.abs(pistons - u)) < 0.8 * np.sum(np.abs(np.round(u) - u))


def test_without_the_setting_a_goto_ends_as_its_plan_does(model):
    acc, plan_s, refs, events, _, _ = _run(model)
    assert acc.duration == pytest.approx(plan_s)
    q = TrajectoryPlanner(model).inverse.solve(np.array(list(GOAL.values())))[0]
    assert build_count_tail(model.profile, q, lambda q: None) is None
    assert len({r for t, r in refs if t > plan_s + 0.1}) == 1  # one reference held after the plan


def test_a_stop_in_the_approach_holds_the_counts_streamed_then(model, offsets):
    """The hitch is at rest in the approach: a stop holds the via counts it streams (the goal's counts would move
    the pistons up to three counts after a stop), and nothing of the approach follows."""
    m = _with_approach(model, offsets)
    _, plan_s, refs, events, _, mc = _run(m, stop_after_plan_s=0.2)
    tail = build_count_tail(
        m.profile, TrajectoryPlanner(m).inverse.solve(np.array(list(GOAL.values())))[0], lambda q: None
    )
    assert tail is not None
    via = tuple(int(c) for c in tail.approach.via_counts)
    held = {r for t, r in refs if t > plan_s + 0.3}
    assert held == {via}
    assert mc._active is None and any(e.get("event") == "motion_aborted" for e in events)
    assert not any(e.get("event") == "motion_finished" for e in events)


def test_no_approach_where_the_link_would_refuse_its_via_or_final(model, offsets):
    m = _with_approach(model, offsets)
    q = TrajectoryPlanner(m).inverse.solve(np.array(list(GOAL.values())))[0]

    def refuse(q):
        raise ReferenceRefused("lift: beyond its hard limit")

    assert build_count_tail(m.profile, q, refuse) is None
    assert build_count_tail(m.profile, q, lambda q: None) is not None


def test_the_twin_stops_each_piston_repeatably_inside_its_count(offsets):
    """The premise: stepped into a count from rest the stop spreads by a few hundredths of a count; the heavy
    lift coasts past the count's middle and the further the faster it came (back-offs 1, 2, 3 kept)."""
    assert offsets.n == 4
    for sd in (*offsets.sd_below, *offsets.sd_above):
        assert max(sd) < 0.05
    lift_b, lift_a = offsets.from_below[0], offsets.from_above[0]
    assert len(lift_b) == 3 and 0.1 < lift_b[0] < lift_b[1] < lift_b[2] < 0.5
    assert len(lift_a) == 3 and -0.1 > lift_a[0] > lift_a[1] > lift_a[2] > -0.5
    for k in range(1, 5):  # the others stop about 0.1 count inside, from either side
        assert -0.2 < offsets.from_below[k][0] < 0.0 < offsets.from_above[k][0] < 0.2


def _count_steps_follow(tp: TrajectoryPlanner, start: MotionState, poses, motion: np.ndarray, free=None):
    """For gotos of ``tp`` to ``poses``: every actuator's count step (via → final count) has the direction in which
    it moves when the pose moves by ``motion`` at the goal (a finite difference of the exact inverse, not the code's
    Jacobian). Returns (actuator steps checked, gotos where ``free``'s tail stepped some actuator the other way)."""
    resolution = SensorScaling(tp.model.profile).resolution
    checked = flipped = 0
    for pose in poses:
        plan = tp.plan_move(start, dict(zip(POSE, map(float, pose), strict=True)))
        tail = plan_count_tail(tp, plan, lambda q: None)
        assert tail is not None
        goal = plan.state_at(plan.duration).position
        dc = (tp.inverse.solve(goal)[0] - tp.inverse.solve(goal - 1e-3 * motion)[0]) / resolution
        moving = np.abs(dc) > 1e-6
        assert np.array_equal(tail.approach.directions[moving], np.sign(dc[moving]).astype(int))
        checked += int(moving.sum())
        if free is not None:
            other = plan_count_tail(free, plan, lambda q: None)
            assert other is not None
            flipped += int(np.any(other.approach.directions[moving] != np.sign(dc[moving])))
    return checked, flipped


def test_with_a_final_approach_each_count_step_moves_the_implement_the_way_the_final_approach_does(model, offsets):
    """Pin play stays taken up on one side: every actuator's last step (via → final count, the goto's last motion)
    has the direction in which the actuator moves when the pose rises by the final approach's offset at the goal
    (a finite difference of the exact inverse, not the code's Jacobian)."""
    fa = {"x": 0.0025, "z": 0.004, "roll": 0.005, "pitch": 0.007}
    m = _with_approach(model, offsets, fa)
    data = m.profile.model_dump()
    data["motion"]["count_approach"]["keep_arrival_side"] = False
    free = TrajectoryPlanner(HitchModel(profile_from_dict(data)))
    poses = candidate_poses(ParametricModel(model.profile), 30, random_only=True, seed=5)[0]
    start = MotionState.at_rest(model.neutral_pose.controlled())
    checked, flipped = _count_steps_follow(TrajectoryPlanner(m), start, poses, np.array(list(fa.values())), free)
    assert checked > 100 and flipped > 0  # without the rule some actuator would have stepped the other way


def test_with_a_final_approach_from_above_each_count_step_falls_the_way_that_approach_does(model, offsets):
    """``side = "above"`` (the second pass of a two-sided measurement): every actuator's count step has the
    direction in which it moves when the pose falls by the offset."""
    fa = {"x": 0.0025, "z": 0.004, "roll": 0.005, "pitch": 0.007}
    tp = TrajectoryPlanner(_with_approach(model, offsets, {**fa, "side": "above"}))
    poses = candidate_poses(ParametricModel(model.profile), 12, random_only=True, seed=5)[0]
    start = MotionState.at_rest(model.neutral_pose.controlled())
    checked, _ = _count_steps_follow(tp, start, poses, -np.array(list(fa.values())))
    assert checked > 40


def test_the_via_and_final_poses_pass_the_guard(model, offsets):
    """An implement's upper height just above the goal: the approach's via and final poses stay below it (a
    via from above is not chosen, or the goto ends as its plan does); without the guard some would not."""
    m = _with_approach(model, offsets)
    tp = TrajectoryPlanner(m)
    guard = Guard(tp)
    start = MotionState.at_rest(model.neutral_pose.controlled())
    above_without = 0
    for pose in candidate_poses(ParametricModel(model.profile), 12, random_only=True, seed=9)[0]:
        plan = tp.plan_move(start, dict(zip(POSE, map(float, pose), strict=True)))
        top = float(pose[1]) + 0.0005
        guard.set_implement_limits(ImplementLimits(upper_height_m=top))
        tail = plan_count_tail(tp, plan, lambda q: None, guard)
        if tail is not None:
            for q in (tail.via_actuators, tail.final_actuators):
                assert m.forward(q).pose.z <= top + 1e-9
        plain = plan_count_tail(tp, plan, lambda q: None)
        assert plain is not None
        above_without += int(any(m.forward(q).pose.z > top for q in (plain.via_actuators, plain.final_actuators)))
    assert above_without > 0


def test_a_back_off_from_which_the_lift_coasts_a_count_over_is_not_kept(model):
    """From 4 counts below the lift comes fast enough to coast into the next count and is driven back (its last
    move falls): the measurement keeps back-offs 1–3 only."""
    poses = candidate_poses(ParametricModel(model.profile), 2, random_only=True, seed=11)[0]
    off = measure_stop_offsets(model, poses, max_back_off_counts=5)
    assert len(off.from_below[0]) == 3 and len(off.from_above[0]) == 3
    assert "lift = [" in off.toml() and off.table()["from_below_counts"]["lift"] == list(off.from_below[0])


def test_measurements_through_the_twin_carry_the_approach_s_stop_inside_the_count(model, offsets):
    """What `hitch calibrate measure-twin --by goto` records with a count approach: the stop the approach
    expects inside the reading's count (fractional counts), which is where the piston truly is."""
    m = _with_approach(model, offsets, {"x": 0.0025, "z": 0.004, "roll": 0.005, "pitch": 0.007})
    poses = candidate_poses(ParametricModel(model.profile), 3, random_only=True, seed=3)[0]
    v = visit_poses(m, poses)
    assert np.all(np.abs(v.counts - np.round(v.counts)) > 0.05)  # not whole counts: the stops inside them
    sc, inverse = SensorScaling(m.profile), TrajectoryPlanner(m).inverse
    true_counts = sc.counts_min + (np.array([inverse.solve(p)[0] for p in v.true]) - sc.si_min) / sc.resolution
    # lift, tilt, top (the limiters of the twin's rigid implement give up a common-mode length: their
    # geometric lengths at the true pose are not their pistons)
    assert np.max(np.abs(v.counts - true_counts)[:, :3]) < 0.08, v.counts - true_counts


def test_the_via_never_leaves_the_workspace_box(model, offsets):
    """A goal on a face: the via that would lie beyond it is shortened to one count, or the goto ends as its plan
    does; every via pose stays inside the box (random goals, and goals on the lower z and upper pitch faces)."""
    m = _with_approach(model, offsets, {"x": 0.0025, "z": 0.004, "roll": 0.005, "pitch": 0.007})
    tp = TrajectoryPlanner(m)
    start = MotionState.at_rest(model.neutral_pose.controlled())
    goals = list(candidate_poses(ParametricModel(model.profile), 20, random_only=True, seed=8)[0])
    for k, lo_or_hi in ((1, tp.lo), (3, tp.hi)):
        for g in goals[:6]:
            g = np.array(g, float)
            g[k] = lo_or_hi[k]
            goals.append(g)
    shortened = none = 0
    for g in goals:
        plan = tp.plan_move(start, dict(zip(POSE, map(float, g), strict=True)))
        tail = plan_count_tail(tp, plan, lambda q: None)
        if tail is None:
            none += 1
            continue
        via = m.forward(tail.via_actuators).pose.controlled()
        assert np.all(via >= tp.lo - 1e-9) and np.all(via <= tp.hi + 1e-9)
        shortened += int(np.all(tail.approach.back_off_counts == 1) and np.any(np.abs(g - tp.lo) < 1e-12))
    assert none + shortened > 0  # the faces did bind
    assert none < len(goals) // 2


def test_presets_and_maneuver_steps_end_as_their_plans_do(model, offsets):
    """Only a goto waits for the count approach: a preset (quick raise, return to work) does not."""
    m = _with_approach(model, offsets)
    with SimRig(m) as rig:
        rig.start()
        rig.run_until(0.5)
        mc = _controller(m, rig, [])
        acc = mc._start_plan(GOAL, 1.0, "preset", "custom", runner=None)
        assert mc._active.tail is None and acc.duration == pytest.approx(mc._active.plan.duration)  # type: ignore[union-attr]
        acc = mc.goto(GOAL)
        assert mc._active.tail is not None  # type: ignore[union-attr]


def test_the_cycle_a_goto_ends_already_streams_the_final_counts(model, offsets):
    """A goal whose chosen count differs from its nearest one: from the via's end on, every cycle streams the
    final counts, the one in which the motion finishes too (it streamed the nearest count once: a valve opened)."""
    m = _with_approach(model, offsets)
    tp = TrajectoryPlanner(m)
    for pose in candidate_poses(ParametricModel(model.profile), 40, random_only=True, seed=21)[0]:
        tail = build_count_tail(m.profile, tp.inverse.solve(pose)[0], lambda q: None)
        assert tail is not None
        if np.any(tail.approach.final_counts != np.round(tail.approach.unrounded_counts)):
            break
    else:
        pytest.fail("no goal whose chosen count differs from the nearest")
    goal = dict(zip(POSE, map(float, pose), strict=True))
    _, plan_s, refs, _, _, _ = _run(m, goal=goal)
    a = tail.approach
    after = [r for t, r in refs if t > plan_s + a.via_hold_s + 0.05]
    assert after and set(after) == {tuple(int(c) for c in a.final_counts)}


def test_a_stop_that_does_not_repeat_is_refused_and_later_back_offs_are_cut():
    """The measurement's rule: a one-count back-off must repeat (sd <= 0.05 count) and stay inside a count;
    a longer one is kept only while its stop moves further in, repeats and stays inside."""
    from bridge.sim.accuracy_run import _kept
    from bridge.sim.rig import SimError

    with pytest.raises(SimError, match=r"lift from below: its stop after a one-count step does not repeat"):
        _kept("lift from below", np.array([0.2]), np.array([0.08]), 1.0)
    kept, _ = _kept("lift from below", np.array([0.19, 0.31, 0.43, -0.19]), np.full(4, 0.02), 1.0)
    assert kept == (0.19, 0.31, 0.43)
    kept, _ = _kept("top from above", np.array([0.12, 0.10, 0.2]), np.array([0.01, 0.01, 0.2]), -1.0)
    assert kept == (0.12, 0.10)


GOAL2 = {"x": -0.015, "z": 0.09, "roll": -0.02, "pitch": 0.01}
GOAL3 = {"x": 0.03, "z": 0.12, "roll": 0.01, "pitch": -0.03}


def _goal_off_the_nearest_count(m: HitchModel) -> dict[str, float]:
    """A goal whose count approach ends on a count other than the goal's nearest in the lift, tilt or top link
    (there, the held counts and the goal's differ after the approach)."""
    tp = TrajectoryPlanner(m)
    for pose in candidate_poses(ParametricModel(m.profile), 40, random_only=True, seed=21)[0]:
        tail = build_count_tail(m.profile, tp.inverse.solve(pose)[0], lambda q: None)
        assert tail is not None
        if np.any(tail.approach.final_counts[:3] != np.round(tail.approach.unrounded_counts[:3])):
            return dict(zip(POSE, map(float, pose), strict=True))
    pytest.fail("no goal whose chosen count differs from the nearest")


def _script(model: HitchModel, goal: dict, actions: list[tuple[float, str, dict | None]], until_s: float):
    """A goto to ``goal``, then ``actions`` (seconds after its plan's end, "goto" with a goal or "stop") through
    the service's controller on the twin, cycles at 50 Hz until ``until_s`` after the plan's end: the counts
    streamed each cycle (time after the plan's end), the controller and when each action ran (same time)."""
    events: list[dict] = []
    with SimRig(model) as rig:
        rig.start()
        rig.run_until(0.5)
        mc = _controller(model, rig, events)
        mc.goto(goal)
        first = mc._active
        assert first is not None and first.tail is not None  # type: ignore[union-attr]
        end = first.t0 + first.plan.duration  # type: ignore[union-attr]
        todo = sorted(actions, key=lambda a: a[0])
        refs: list[tuple[float, tuple[int, ...]]] = []
        ran: list[float] = []
        while rig.now_s < end + until_s - 1e-9:
            while todo and rig.now_s >= end + todo[0][0] - 1e-9:
                _, what, g = todo.pop(0)
                ran.append(rig.now_s - end)
                if what == "stop":
                    mc.stop()
                else:
                    assert g is not None
                    mc.goto(g)
            rig.run_until(rig.now_s + 0.02)
            mc.cycle()
            ref = rig.ecu.reference_counts()
            if ref is not None:
                refs.append((rig.now_s - end, tuple(int(c) for c in ref)))
        return refs, mc, ran


def _leaves_straight(held: tuple[int, ...], refs: list[tuple[int, ...]]) -> None:
    """The first two cycles stream the ``held`` counts (the sway limiters within one count: five actuators
    over-determine four DOF, so the pose of whole counts takes them back a fraction of a count); then the lift,
    tilt and top link leave them straight for the new goal (no step back first), and every actuator from rest,
    jerk-limited (at most two counts a cycle in the first half, the feed-forward leading a little)."""
    seq = np.array([held, *refs])
    assert np.all(seq[1:3, :3] == seq[0, :3]) and np.all(np.abs(seq[1:3, 3:] - seq[0, 3:]) <= 1), seq[:3]
    d = np.diff(seq, axis=0)
    for k in range(3):
        assert np.all(d[:, k] >= 0) or np.all(d[:, k] <= 0), (k, seq[:, k])
    assert np.abs(d[: len(refs) // 2]).max() <= 2, seq


@pytest.mark.parametrize(
    ("after_plan_s", "stop_first"),
    [(0.2, True), (2.0, False), (0.2, False)],
    ids=["stopped-in-the-via", "held-after-the-approach", "replacing-in-the-via"],
)
def test_the_next_goto_starts_from_the_counts_held_not_from_the_goal(model, offsets, after_plan_s, stop_first):
    """After a count approach the pistons rest on its counts, up to three away from the goal's: the next goto (or
    one replacing it in its via) starts from those counts. It started from the goal, so its first references
    stepped to the goal's counts (the pistons moved by up to three counts at once, before its plan did). The
    goal's approach ends off its nearest count, so even after the approach the two differ."""
    m = _with_approach(model, offsets)
    goal = _goal_off_the_nearest_count(m)
    t_next = after_plan_s + (0.5 if stop_first else 0.0)
    actions: list[tuple[float, str, dict | None]] = [(t_next, "goto", GOAL2)]
    if stop_first:
        actions.append((after_plan_s, "stop", None))
    refs, mc, ran = _script(m, goal, actions, t_next + 0.08 + 0.3)
    t_req = max(ran)
    before = [r for t, r in refs if t < t_req]
    held = before[-1]
    assert len(set(before[-5:])) == 1  # at rest on them
    _leaves_straight(held, [r for t, r in refs if t > t_req])


def test_a_stop_in_the_lead_of_a_goto_that_replaced_one_in_its_approach_holds_the_approach_s_counts(model, offsets):
    """A goto replaces one in its count approach; a stop comes before the new plan starts (in its lead): the
    pistons stay on the counts streamed then (they stepped to the first goal's counts and stayed, after the stop)."""
    m = _with_approach(model, offsets)
    refs, mc, ran = _script(m, GOAL, [(0.2, "goto", GOAL2), (0.22, "stop", None)], 1.5)
    at_stop = [r for t, r in refs if t < ran[1]][-1]
    assert ran[1] - ran[0] < 0.08  # the stop came in the new goto's lead
    assert {r for t, r in refs if t > ran[1]} == {at_stop}
    assert mc._active is None


def test_gotos_replacing_each_other_within_the_lead_start_from_the_approach_s_counts(model, offsets):
    """Two gotos 20 ms apart, the first replacing one in its count approach: until the last plan starts, the
    approach's counts are streamed, and then each actuator leaves them straight (the second goto's lead fell
    through to the first goal's counts: a step back before the new plan)."""
    m = _with_approach(model, offsets)
    refs, mc, ran = _script(m, GOAL, [(0.2, "goto", GOAL2), (0.22, "goto", GOAL3)], 0.22 + 0.08 + 0.3)
    assert ran[1] - ran[0] < 0.08  # the second goto came in the first one's lead
    held = [r for t, r in refs if t < ran[0]][-1]
    last = mc._active
    assert last is not None and last.prev is None  # type: ignore[union-attr]
    _leaves_straight(held, [r for t, r in refs if t > ran[0]])


def test_the_state_s_reference_is_the_approach_s_counts_and_their_pose(model, offsets):
    """While the approach runs and after it, the reference the state message reports is what is streamed: the
    via, then the final counts (SI), with their pose through the forward kinematics (it showed the goal's exact
    actuators and pose)."""
    m = _with_approach(model, offsets)
    with SimRig(m) as rig:
        rig.start()
        rig.run_until(0.5)
        mc = _controller(m, rig, [])
        mc.goto(GOAL)
        motion = mc._active
        tail = motion.tail  # type: ignore[union-attr]
        assert tail is not None
        end = motion.t0 + motion.plan.duration  # type: ignore[union-attr]
        seen = []
        for t_after in (0.3, tail.approach.via_hold_s + 0.3, tail.approach.duration_s + 0.5):
            while rig.now_s < end + t_after - 1e-9:
                rig.run_until(rig.now_s + 0.02)
                mc.cycle()
            ref = mc._reference
            assert ref is not None
            q = tail.actuators_at(t_after)
            np.testing.assert_allclose(ref.actuators, q, atol=1e-12)
            pose = m.forward(q).pose.controlled()
            np.testing.assert_allclose(ref.state.position, pose, atol=1e-9)
            seen.append(tuple(SensorScaling(m.profile).to_counts(ref.actuators)))
        assert seen[0] == tuple(tail.approach.via_counts) and seen[1] == seen[2] == tuple(tail.approach.final_counts)
        assert not np.allclose(pose, list(GOAL.values()), atol=1e-6)  # the counts' pose is not the goal's


def test_a_plan_preview_lasts_as_long_as_the_goto_with_its_count_approach(model, offsets, tmp_path):
    """The ``plan`` preview (in the service's threads and in a planning process alike) includes the count approach
    the goto would end with: its duration is the goto's accepted duration (it gave the plan's own, 1.2 s less)."""
    from bridge.service.planning import GuardPlanning, InProcessPlanning
    from bridge.service.workers import WorkerSpec, _WorkerContext
    from bridge.sim.truth import truth_toml

    m = _with_approach(model, offsets)
    path = tmp_path / "count-approach.toml"
    path.write_text(truth_toml(m.profile.model_dump()))
    with SimRig(m) as rig:
        rig.start()
        rig.run_until(0.5)
        mc = _controller(m, rig, [])
        start = mc.preview_start()
        local = InProcessPlanning(mc, None).preview(start, GOAL, 1.0)
        remote = _WorkerContext(WorkerSpec(str(path), None, m.profile.motion.control_rate, None)).run(
            "preview", (start, GOAL, 1.0)
        )
        acc = mc.goto(GOAL)
    a = m.profile.motion.count_approach
    assert a is not None and local["ok"]
    assert local["count_approach_s"] == pytest.approx(a.via_hold_s + a.final_hold_s)
    assert local["duration"] == pytest.approx(acc.duration, abs=1e-9)
    assert remote == local
    own_guard = InProcessPlanning(GuardPlanning(Guard(TrajectoryPlanner(m))), None)  # a core in another process
    assert own_guard.preview(start, GOAL, 1.0) == local
    plain = InProcessPlanning(GuardPlanning(Guard(TrajectoryPlanner(model))), None).preview(start, GOAL, 1.0)
    assert plain["ok"] and plain["count_approach_s"] == 0.0
    assert plain["duration"] == pytest.approx(local["duration"] - local["count_approach_s"], abs=1e-9)


def test_a_short_via_hold_gives_the_same_tails_the_default_does():
    """A review: the guard's check of a tail's via and final pose judged the count steps as speeds over the made-up
    times 0, hold, 2·hold (the mean velocity between samples): with via_hold_s 0.1, 15 of 39 tails fell back to
    one-count back-offs, with 0.05 7 of 40 were lost. They are poses at rest (Guard.check_setpoints rest_poses)."""
    import numpy as np

    from planner.limits.guard import Guard
    from planner.model.kinematics import HitchModel
    from planner.profiles import profile_from_dict
    from planner.trajectory import MotionState, TrajectoryPlanner

    base = HitchModel.from_profile("thesis-t132", "2")
    table = {
        "from_below_counts": {
            "lift": [0.193, 0.305, 0.426],
            "tilt": [-0.089, -0.087, -0.084],
            "top": [-0.124, -0.123, -0.119],
            "left": [-0.115, -0.111],
            "right": [-0.113, -0.109],
        },
        "from_above_counts": {
            "lift": [-0.196, -0.306, -0.452],
            "tilt": [0.083],
            "top": [0.116, 0.108],
            "left": [0.064],
            "right": [0.114],
        },
    }
    tails = {}
    for hold in (0.6, 0.05):
        data = base.profile.model_dump()
        data["motion"]["count_approach"] = dict(table, via_hold_s=hold)
        tp = TrajectoryPlanner(HitchModel(profile_from_dict(data)))
        g = Guard(tp)
        s0 = MotionState.at_rest((tp.lo + tp.hi) / 2)
        rng = np.random.default_rng(8)
        out = []
        for _ in range(40):
            goal = tp.lo + (tp.hi - tp.lo) * rng.random(4)
            plan = tp.plan_move(s0, dict(zip(("x", "z", "roll", "pitch"), goal, strict=True)))
            tail = plan_count_tail(tp, plan, lambda q: None, g)
            out.append(None if tail is None else (tuple(tail.via_actuators), tuple(tail.final_actuators)))
        tails[hold] = out
    assert sum(t is not None for t in tails[0.6]) >= 30
    assert tails[0.05] == tails[0.6]
