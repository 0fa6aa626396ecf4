"""The motion controller in simulated time: the real CAN path (link + simulated ECU on a private
virtual bus, :class:`bridge.sim.move.SimRig`), control cycles driven by the test at 50 Hz.

Truth used: the goal itself (the commanded reference must end exactly there; the measured pose
within the closed loop's accuracy), the workspace box, the jerk-limited plan continuity (the new
plan starts from the old plan's exact state), and the precedence rules stop > jog > goto.
"""

from __future__ import annotations

import uuid

import can
import numpy as np
import pytest

from bridge.service.maneuvers.language import PlanningContext, validate
from bridge.service.motion.controller import MotionController
from bridge.service.motion.types import ATTACH_SPEED_SCALE, MotionError, plan_state
from bridge.service.odometer import SimulatedTractor, WheelOdometer
from bridge.sim.move import SimRig
from planner.limits.guard import Guard
from planner.trajectory import TrajectoryPlanner, straight_line_limits

DT = 0.02
POSE = ("x", "z", "roll", "pitch")


class Bench:
    """A controller on a simulated rig; ``run`` advances simulated time with a cycle every 20 ms."""

    def __init__(self, model):
        self.rig = SimRig(model)
        self.rig.start()
        self.rig.run_until(0.5)  # address claims (250 ms) and the first measurements
        self.states, self.events = [], []
        ch = f"tractor-{uuid.uuid4().hex}"  # the simulated tractor's wheel-based speed, 2 m/s
        self.buses = [can.Bus(interface="virtual", channel=ch) for _ in range(2)]
        self.tractor, self.odometer = SimulatedTractor(self.buses[0], 2.0), WheelOdometer(self.buses[1])
        self.mc = MotionController(
            Guard(TrajectoryPlanner(model)),
            Guard(TrajectoryPlanner(model)),
            self.rig.link,
            lambda: self.rig.now_s,
            on_state=self.states.append,
            on_event=self.events.append,
            spawn=lambda fn: fn(),
            odometer=self.odometer.distance_m,
        )
        self.run(0.1)

    def run(self, seconds: float, *, ecu: bool = True, each=None) -> None:
        end = self.rig.now_s + seconds
        while self.rig.now_s < end - 1e-9:
            t = self.rig.now_s + DT
            if ecu:
                self.rig.run_until(t)
            else:  # the ECU falls silent: only the link runs
                while self.rig.now_s < t - 1e-9:
                    self.rig._k += 1
                    self.rig.link.poll(self.rig.now_s)
            self.tractor.poll(self.rig.now_s)
            self.odometer.poll(self.rig.now_s)
            if each is not None:
                each()
            self.mc.cycle()

    def run_until_rest(self, limit_s: float = 15.0) -> None:
        end = self.rig.now_s + limit_s
        self.run(DT)
        while self.states[-1]["moving"] and self.rig.now_s < end:
            self.run(DT)
        assert not self.states[-1]["moving"], "motion did not end"

    def ref(self) -> np.ndarray:
        return np.array([self.states[-1]["reference"]["pose"][k] for k in POSE])

    def measured(self) -> np.ndarray:
        return np.array([self.states[-1]["pose"][k] for k in POSE])

    def names(self) -> list[str]:
        return [e["event"] for e in self.events]

    def close(self) -> None:
        self.rig.close()
        for b in self.buses:
            b.shutdown()


@pytest.fixture
def bench(model):
    b = Bench(model)
    yield b
    b.close()


def test_goto_reaches_the_goal_through_the_can_path(bench):
    start = bench.measured()
    acc = bench.mc.goto({"x": 0.02, "z": 0.25})
    assert acc.motion_id == 1 and acc.duration > 0
    bench.run(acc.duration + 1.5)
    assert not bench.states[-1]["moving"]
    goal = np.array([0.02, 0.25, start[2], start[3]])  # partial goal: roll and pitch kept
    np.testing.assert_allclose(bench.ref(), goal, atol=1e-9)
    err = bench.measured() - goal
    assert abs(err[0]) < 5e-3 and abs(err[1]) < 5e-3, err  # closed loop, quantised sensors
    assert abs(err[2]) < 0.01 and abs(err[3]) < 0.01, err
    assert bench.names().count("motion_started") == 1 and bench.names().count("motion_finished") == 1
    fin = [e for e in bench.events if e["event"] == "motion_finished"][0]
    assert fin["motion_id"] == acc.motion_id
    assert bench.states[-1]["ecu"]["online"] and bench.states[-1]["ecu"]["references_refused"] == 0


def test_state_messages_are_consecutive_and_complete(bench):
    bench.run(0.2)
    seqs = [s["seq"] for s in bench.states]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    s = bench.states[-1]
    for k in (
        "t",
        "seq",
        "pose",
        "actuators",
        "velocity",
        "mode",
        "moving",
        "motion_id",
        "limited",
        "kinematic_margin",
        "stability",
        "ecu",
        "maneuver",
    ):
        assert k in s
    assert set(s["ecu"]) >= {"online", "watchdog", "faults"}
    assert s["stability"]["ok"] and s["stability"]["ssm"] > 0


def test_a_cycle_sends_its_reference_before_the_states_guard_evaluations(bench, monkeypatch):
    """Setpoint-to-reference latency: the cycle's reference reaches the bus before the state's
    kinematic margin and stability are evaluated (they took the cycle's first milliseconds before),
    and the state is still stamped at the cycle's start, before that reference."""
    import time

    order: list[str] = []
    sent_at: list[float] = []
    link, guard = bench.rig.link, bench.mc.guard
    send, margin, stability = link.send_reference, guard.margin, guard.stability_at

    def spy_send(*a, **k):
        order.append("reference")
        sent_at.append(time.time())
        return send(*a, **k)

    monkeypatch.setattr(link, "send_reference", spy_send)
    monkeypatch.setattr(guard, "margin", lambda *a, **k: (order.append("margin"), margin(*a, **k))[1])
    monkeypatch.setattr(guard, "stability_at", lambda *a, **k: (order.append("stability"), stability(*a, **k))[1])
    acc = bench.mc.goto({"z": 0.28})
    both = 0
    for _ in range(25):  # moving (after the switch time): a new reference and new counts every cycle
        order.clear()
        sent_at.clear()
        before = len(bench.states)
        bench.run(DT)
        assert len(bench.states) == before + 1
        if "reference" in order and "margin" in order:
            both += 1
            assert order.index("reference") < order.index("margin"), order
            if "stability" in order:
                assert order.index("reference") < order.index("stability"), order
            assert bench.states[-1]["t"] <= sent_at[0]
    assert acc.duration > 0 and both >= 15, both


def test_a_new_goto_replaces_the_running_one_smoothly(bench):
    first = bench.mc.goto({"z": 0.28})
    bench.run(0.6)
    old = bench.mc._active
    second = bench.mc.goto({"x": 0.04, "z": 0.0})
    new = bench.mc._active
    assert second.motion_id == first.motion_id + 1 and new.prev is old
    handover = plan_state(old, new.t0)  # the new plan starts from the old one's exact state
    np.testing.assert_allclose(new.plan.start.position, handover.position, atol=1e-12)
    np.testing.assert_allclose(new.plan.start.velocity, handover.velocity, atol=1e-12)
    np.testing.assert_allclose(new.plan.start.acceleration, handover.acceleration, atol=1e-12)
    assert np.linalg.norm(handover.velocity) > 1e-3  # it really was moving
    bench.run_until_rest()
    vel = np.array([[s["velocity"][k] for k in POSE] for s in bench.states if s["reference"] is not None])
    dv = np.abs(np.diff(vel, axis=0)) / DT  # mean pose-space acceleration between cycles
    tp = bench.mc.planner  # bound: the limits either plan may use
    a_max = np.maximum.reduce(
        [
            tp.any_direction.acceleration,
            straight_line_limits(
                tp.inverse, old.plan.start.position, old.plan.state_at(old.plan.duration).position, tp.limits
            ).acceleration,
            straight_line_limits(
                tp.inverse, handover.position, new.plan.state_at(new.plan.duration).position, tp.limits
            ).acceleration,
        ]
    )
    assert np.all(dv <= a_max * (1 + 1e-6) + 1e-9), (dv.max(axis=0), a_max)
    jump = np.abs(vel[1:] - vel[:-1]).max(axis=0)  # a restart from rest would jump by |v| at once
    assert jump.max() < 0.5 * np.abs(handover.velocity).max()
    assert [e["reason"] for e in bench.events if e["event"] == "motion_aborted"] == ["replaced by goto"]
    np.testing.assert_allclose(bench.ref()[:2], [0.04, 0.0], atol=1e-9)


def test_jog_takes_over_a_goto_and_dies_with_its_ttl(bench):
    bench.mc.goto({"z": 0.28})
    bench.run(0.5)
    j = bench.mc.jog({"vx": 0.02}, 0.2)
    assert "motion_aborted" in bench.names()
    with pytest.raises(MotionError) as ei:  # jog > goto while the jog command is live
        bench.mc.goto({"z": 0.0})
    assert ei.value.code == "busy" and "jog" in str(ei.value)
    bench.run_until_rest()
    assert bench.states[-1]["motion_id"] == j.motion_id
    (fin,) = [e for e in bench.events if e["event"] == "motion_finished" and e["motion_id"] == j.motion_id]
    assert fin["reason"].startswith("released: no jog command within its ttl"), fin  # it gave none (an operator)
    assert np.allclose([bench.states[-1]["velocity"][k] for k in POSE], 0.0)
    assert bench.mc.goto({"z": 0.1}).motion_id > j.motion_id  # after the dead-man stop, goto is accepted


def test_jog_stops_at_the_workspace_face_and_says_so(bench):
    x_max = bench.mc.planner.workspace["x"][1]
    xs = []

    def hold():
        bench.mc.jog({"vx": 0.05}, 0.2)
        xs.append(bench.mc.current_state().position[0])

    bench.run(3.0, each=hold)
    assert max(xs) <= x_max + 1e-9
    assert max(xs) > x_max - 0.005  # it did get there
    assert bench.states[-1]["limited"].get("x+") == "workspace:x:max"
    reached = [e["limits"].get("x+") for e in bench.events if e["event"] == "limit_reached"]
    # 0.05 m/s is above x's jog speed limit: capped and said so, then the face, each announced once
    assert reached == ["velocity:x", "workspace:x:max"], reached


def test_a_guard_limit_held_over_many_cycles_is_announced_once(bench):
    """A track setpoint above the workspace drives the lift at its speed limit (up to the face, outside its
    end-stop zone: named velocity:lift since the guard tells the two apart): the guard's speed reason holds for a
    second, its factor changing every cycle. Each factor was announced as a new limit: a ``limit_reached`` event
    every 100 ms (a fleet integrator's report: 11 in 1.1 s)."""
    z_hi = bench.mc.planner.workspace["z"][1]
    session = bench.mc.track_start("tractor", ("z", "roll"), 1.0).session
    bench.mc.track_setpoint(session, 1, {"z": z_hi + 0.01, "roll": 0.0})
    bench.run(1.5)
    announced = [k for e in bench.events if e["event"] == "limit_reached" for k in e["limits"]]
    assert announced.count("velocity:lift") == 1 and "end_stop:lift" not in announced, announced
    assert announced.count("z") == 1  # the workspace face (the follower's clip), once


def test_a_jog_above_its_speed_limit_is_capped_and_says_which_limit(bench):
    """The old jog clipped a rate above the jog speed limit silently (``limited`` empty)."""
    v_max = bench.mc.planner.any_direction.velocity[1]
    acc = bench.mc.jog({"vz": 2 * v_max}, 0.5)
    assert acc.limited == {"z+": "velocity:z"}
    bench.run(1.0, each=lambda: bench.mc.jog({"vz": 2 * v_max}, 0.5))
    st = bench.states[-1]
    assert st["limited"] == {"z+": "velocity:z"}
    assert max(s["velocity"]["z"] for s in bench.states) <= v_max * (1 + 1e-9)  # never beyond the limit
    assert st["velocity"]["z"] == pytest.approx(v_max, rel=1e-6)  # reached and held at it
    assert bench.mc.jog({"vz": 0.5 * v_max}, 0.5).limited == {}  # within the limit: nothing said


def test_stop_has_precedence_and_goto_waits_for_rest(bench):
    assert bench.mc.stop() is None  # at rest: nothing to stop
    bench.mc.goto({"z": 0.28})
    bench.run(0.4)
    sid = bench.mc.stop()
    assert sid is not None
    for cmd in (lambda: bench.mc.goto({"z": 0.0}), lambda: bench.mc.jog({"vz": 0.01}, 0.2)):
        with pytest.raises(MotionError) as ei:
            cmd()
        assert ei.value.code == "busy" and "stop" in str(ei.value)
    bench.run_until_rest()
    assert any(e["event"] == "motion_finished" and e["motion_id"] == sid for e in bench.events)
    assert bench.mc.goto({"z": 0.1}).motion_id == sid + 1


def test_modes_gate_motion(bench):
    bench.mc.set_mode("manual")
    for cmd in (lambda: bench.mc.goto({"z": 0.2}), lambda: bench.mc.jog({"vz": 0.01}, 0.2)):
        with pytest.raises(MotionError) as ei:
            cmd()
        assert ei.value.code == "mode" and "manual" in str(ei.value)
    bench.mc.set_mode("attach")
    with pytest.raises(MotionError):
        bench.mc.goto({"z": 0.2})
    vmax = bench.mc.planner.any_direction.velocity[1]
    vz = []
    # the reply says what caps the jog (a field operator's report: quarter speed with "limited": {} before)
    assert bench.mc.jog({"vz": 1.0}, 0.2).limited["z+"] == "mode:attach"
    bench.run(1.0, each=lambda: (bench.mc.jog({"vz": 1.0}, 0.2), vz.append(bench.mc.current_state().velocity[1])))
    assert max(vz) <= ATTACH_SPEED_SCALE * vmax * (1 + 1e-6) and max(vz) > 0.5 * ATTACH_SPEED_SCALE * vmax
    # and the state says so while it lasts ("Control limited" showed nothing: a terminal trial)
    assert bench.states[-1]["limited"].get("z+") == "mode:attach", bench.states[-1]["limited"]
    with pytest.raises(MotionError) as ei:  # mode change while moving: refused
        bench.mc.set_mode("auto")
    assert ei.value.code == "busy" and "send stop first" in str(ei.value)
    bench.mc.stop()
    with pytest.raises(MotionError) as ei:  # while the stop brakes: nothing to stop, wait for rest
        bench.mc.set_mode("auto")
    assert "braking to rest" in str(ei.value) and "send stop" not in str(ei.value), str(ei.value)
    bench.run_until_rest()
    assert bench.mc.set_mode("auto") == "auto"
    with pytest.raises(MotionError):
        bench.mc.set_mode("turbo")


def test_ecu_silence_aborts_and_only_a_fresh_command_moves_again(bench):
    acc = bench.mc.goto({"z": 0.28})
    bench.run(0.5)
    bench.run(0.4, ecu=False)  # > 200 ms without measurements
    assert "fault" in bench.names()
    aborted = [e for e in bench.events if e["event"] == "motion_aborted"]
    assert aborted and aborted[-1]["motion_id"] == acc.motion_id and "fault" in aborted[-1]["reason"]
    assert not bench.rig.link.streaming and not bench.states[-1]["moving"]
    bench.run(1.0)  # the ECU is back: nothing moves by itself
    assert not bench.rig.link.streaming and bench.states[-1]["reference"] is None
    again = bench.mc.goto({"z": 0.1})
    bench.run(again.duration + 1.0)
    assert abs(bench.measured()[1] - 0.1) < 5e-3 and bench.states[-1]["ecu"]["faults"] == []


def test_maneuver_runs_its_steps_and_a_stop_aborts_it(bench):
    script = "name: m\nsteps:\n  - goto: {z: 0.25}\n  - wait: 0.2\n  - goto: {x: 0.03, speed_scale: 0.5}\n"
    ctx = PlanningContext(bench.mc.current_state(), bench.mc.plan_step, lambda name: None)
    res = validate(script, ctx)
    assert res.ok, res.errors
    mid = bench.mc.run_maneuver(res, "m")
    bench.run(res.duration + 2.0)
    names = bench.names()
    assert names.count("maneuver_step") == 3 and "maneuver_finished" in names
    assert all(e.get("maneuver_id") == mid for e in bench.events if e["event"].startswith("maneuver_"))
    # a step's motion ends before the maneuver goes on: its motion_finished precedes the next step and the
    # maneuver's end (they came after them, in the same cycle: a fleet integrator's report)
    seq = [e["event"] for e in bench.events if e["event"] in ("maneuver_step", "motion_finished", "maneuver_finished")]
    assert seq == ["maneuver_step", "motion_finished", "maneuver_step", "maneuver_step", "motion_finished"] + [
        "maneuver_finished"
    ], seq
    np.testing.assert_allclose(bench.ref()[:2], [0.03, 0.25], atol=1e-9)
    bench.mc.run_maneuver(
        validate(
            script.replace("0.25", "0.0"),
            PlanningContext(bench.mc.current_state(), bench.mc.plan_step, lambda name: None),
        ),
        "m2",
    )
    bench.run(0.5)
    assert bench.states[-1]["maneuver"]["name"] == "m2"
    bench.mc.stop()
    assert [e for e in bench.events if e["event"] == "maneuver_aborted"][-1]["reason"] == "stop"
    bench.run_until_rest()
    assert bench.states[-1]["maneuver"] is None


def test_a_stop_that_ends_a_waiting_maneuver_says_so(bench):
    """An operator's trial: a stop during a maneuver's wait (no motion to brake) answered only "at rest"
    (``motion_id`` null) while the log said ``maneuver_aborted reason=stop``."""
    script = "name: mw\nsteps:\n  - wait: 4\n  - goto: {z: 0.05}\n"
    res = validate(script, PlanningContext(bench.mc.current_state(), bench.mc.plan_step, lambda name: None))
    assert res.ok, res.errors
    bench.mc.run_maneuver(res, "mw")
    bench.run(0.5)
    report = bench.mc.stop_report()
    assert report == {"motion_id": None, "ended": ["maneuver 'mw' at step 1 (index 0)"]}, report
    assert bench.mc.stop_report() == {"motion_id": None, "ended": []}  # nothing left to end
    unnamed = validate(
        script.replace("name: mw\n", ""),
        PlanningContext(bench.mc.current_state(), bench.mc.plan_step, lambda name: None),
    )
    mid = bench.mc.run_maneuver(unnamed, None)  # run unnamed: said by its id, not "maneuver None" (a review)
    bench.run(0.5)
    assert bench.mc.stop_report()["ended"] == [f"maneuver #{mid} at step 1 (index 0)"]


def test_a_mode_change_during_a_track_session_names_the_session_not_motion(bench):
    """An operator's trial: with levelling on and the hitch still, manual was refused "while the hitch is moving
    (motion 1)"."""
    session = bench.mc.track_start("tractor", ("roll",), 1.0).session
    bench.run(0.2)
    with pytest.raises(MotionError) as err:
        bench.mc.set_mode("manual")
    text = str(err.value)
    assert f"while track session {session} (tractor frame) follows its setpoints" in text, text
    assert "moving" not in text and "track/stop" in text


def test_a_maneuver_a_link_fault_ends_says_fault_not_stop(bench):
    """A field operator's report: a maneuver ended by the ECU falling silent said `aborted (stop: link fault …)`,
    read as someone pressing STOP."""
    script = "name: m\nsteps:\n  - goto: {z: 0.25}\n  - wait: 0.2\n  - goto: {z: 0.0}\n"
    res = validate(script, PlanningContext(bench.mc.current_state(), bench.mc.plan_step, lambda name: None))
    assert res.ok, res.errors
    bench.mc.run_maneuver(res, "m")
    bench.run(0.5)
    bench.run(0.6, ecu=False)  # silent beyond the 0.2 s stale limit
    (aborted,) = [e for e in bench.events if e["event"] == "maneuver_aborted"]
    assert aborted["reason"] == "fault" and aborted["message"].startswith("link fault"), aborted


def test_wait_for_waits_for_the_distance_travelled(bench):
    script = "steps:\n  - wait_for: {distance: 3.0}\n  - goto: {z: 0.2}\n"
    res = validate(script, PlanningContext(bench.mc.current_state(), bench.mc.plan_step, lambda name: None))
    assert res.ok and res.distance_m == 3.0
    bench.run(0.3)  # the odometer has heard the tractor
    d0 = bench.odometer.distance_m()
    bench.mc.run_maneuver(res, "drive")
    starts = []
    bench.run(3.0, each=lambda: starts.append(bench.odometer.distance_m()) if bench.mc._active else None)
    assert starts, "the goto step never started"
    travelled = starts[0] - d0  # 2 m/s: the goto starts after ~1.5 s, ~3 m
    assert 3.0 <= travelled <= 3.0 + 2.0 * 0.2, travelled


def test_goto_right_after_a_jog_died_starts_from_its_braking_state(bench):
    def refresh():
        bench.mc.jog({"vx": 0.03}, 0.05)

    bench.run(0.6, each=refresh)  # jogging at speed, the command refreshed every cycle
    v_jog = bench.mc.current_state().velocity[0]
    assert v_jog > 0.01
    bench.rig.run_until(bench.rig.now_s + 0.06)  # the command dies, no cycle has run since
    acc = bench.mc.goto({"z": 0.2})
    new = bench.mc._active
    assert new.prev is not None and new.prev.kind == "jog"  # the jog's braking plan runs until the switch
    handover = plan_state(new.prev, new.t0)
    np.testing.assert_allclose(new.plan.start.velocity, handover.velocity, atol=1e-12)
    bench.run(acc.duration + 0.5)
    vel = np.array([[s["velocity"][k] for k in POSE] for s in bench.states if s["reference"] is not None])
    tp = bench.mc.planner
    # a switch brakes the motion it replaces with the actuators' real limits (issue #14), then moves
    a_max = np.maximum.reduce(
        [
            tp.any_direction.acceleration,
            straight_line_limits(
                tp.inverse, handover.position, new.plan.state_at(new.plan.duration).position, tp.limits
            ).acceleration,
            tp.braking_limits(handover).acceleration,
        ]
    )
    assert np.all(np.abs(np.diff(vel, axis=0)) / DT <= a_max * (1 + 1e-6) + 1e-9)
