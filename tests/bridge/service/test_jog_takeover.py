"""A jog taking over a goto at full speed, through the product path: the motion controller
driven cycle by cycle on simulated time over the simulated CAN rig (link + simulated ECU).

Truth used: the workspace box of the planner (the commanded reference must stay within the
sensor quantisation of it, 2 mm / 2 mrad; the measured pose within the closed loop's accuracy),
the goto's own plan (the jog takes over when the goto starts braking for the face: at its top
speed), and the rules that a motion back into the workspace is always accepted and one further
out refused, naming the face.
"""

from __future__ import annotations

import numpy as np
import pytest

from bridge.service.motion.controller import MotionController
from bridge.sim.move import SimRig
from planner.limits.guard import Guard
from planner.trajectory import PlanError, TrajectoryPlanner

DT = 0.02
POSE = ("x", "z", "roll", "pitch")
RATES = ("vx", "vz", "vroll", "vpitch")
BOUND = 2e-3  # m or rad: the sensor quantisation the commanded motion may leave the workspace by
TRACKING = 5e-3  # m or rad: the measured pose, closed loop on quantised sensors (as for any goto)

# (dof, +1 towards the upper face / -1 towards the lower one), one face or a corner
FACES = [((d, s),) for d in range(4) for s in (1, -1)] + [((0, 1), (1, 1)), ((1, -1), (2, -1), (3, -1))]


def _face_id(face) -> str:
    return "+".join(f"{POSE[d]}{'+' if s > 0 else '-'}" for d, s in face)


class Rig:
    """The controller on a simulated rig; ``cycle`` advances 20 ms and runs one control cycle."""

    def __init__(self, model, start: np.ndarray):
        self.tp = TrajectoryPlanner(model)
        self.rig = SimRig(model, initial_actuators=self.tp.inverse.solve_full(start)[0])
        self.rig.start()
        self.rig.run_until(0.5)  # address claims and the first measurements
        self.mc = MotionController(
            Guard(TrajectoryPlanner(model)),
            Guard(TrajectoryPlanner(model)),
            self.rig.link,
            lambda: self.rig.now_s,
            spawn=lambda fn: fn(),
        )
        self.out_ref = np.zeros(4)  # worst excursion beyond the workspace: commanded, measured
        self.out_measured = np.zeros(4)
        for _ in range(5):
            self.cycle()

    def outside(self, p: np.ndarray) -> np.ndarray:
        return np.maximum(np.maximum(p - self.tp.hi, self.tp.lo - p), 0.0)

    def measured(self) -> np.ndarray:
        ls = self.rig.link.latest_state()
        assert ls is not None
        return ls.pose.controlled()

    def cycle(self, each=None) -> None:
        self.rig.run_until(self.rig.now_s + DT)
        if each is not None:
            each()
        self.mc.cycle()
        self.out_ref = np.maximum(self.out_ref, self.outside(self.mc.current_state().position))
        self.out_measured = np.maximum(self.out_measured, self.outside(self.measured()))

    def close(self) -> None:
        self.rig.close()


@pytest.mark.parametrize("face", FACES, ids=_face_id)
def test_jog_taking_over_a_full_speed_goto_stays_in_the_workspace(model, face):
    tp = TrajectoryPlanner(model)
    centre = (tp.lo + tp.hi) / 2
    goal = centre.copy()
    for d, s in face:
        goal[d] = tp.hi[d] if s > 0 else tp.lo[d]
    r = Rig(model, centre)
    try:
        acc = r.mc.goto(dict(zip(POSE, goal, strict=True)))
        d0, s0 = face[0]
        prev, top = 0.0, 0.0
        for _ in range(int(acc.duration / DT) + 1):  # until the goto starts braking for the face
            r.cycle()
            v = s0 * r.mc.current_state().velocity[d0]
            top = max(top, v)
            if v < prev and v > 0.5 * top:
                break
            prev = v
        assert top > 1.5 * tp.any_direction.velocity[d0] / len(face), "the goto never got fast"
        rates = {RATES[d]: float(s) for d, s in face}  # the operator jogs on towards the face

        def jog() -> None:
            r.mc.jog(rates, 0.2)

        for _ in range(50):
            r.cycle(jog)
        for k in range(300):  # the dead-man stop (the last command's TTL runs out first)
            r.cycle()
            if k > 15 and not r.mc.current_state().moving:
                break
        assert not r.mc.current_state().moving
        assert np.all(r.out_ref <= BOUND), f"commanded pose left the workspace by {r.out_ref} (m, rad)"
        assert np.all(r.out_measured <= TRACKING), f"measured pose left the workspace by {r.out_measured} (m, rad)"
        # and every goto is accepted afterwards
        back = r.mc.goto(dict(zip(POSE, centre, strict=True)))
        assert back.duration > 0
    finally:
        r.close()


def test_from_outside_the_workspace_a_goto_back_in_runs_and_one_further_out_is_refused(model):
    tp = TrajectoryPlanner(model)
    centre = (tp.lo + tp.hi) / 2
    start = centre.copy()
    start[1] = tp.hi[1] + 0.015  # 15 mm above the workspace (after manual motion, say)
    r = Rig(model, start)
    try:
        assert r.measured()[1] > tp.hi[1] + 0.01
        with pytest.raises(PlanError, match="workspace:z:max"):
            r.mc.goto({"z": tp.hi[1] + 0.03})
        acc = r.mc.goto({"z": 0.1})
        zs = []
        for _ in range(int(acc.duration / DT) + 50):
            r.cycle()
            zs.append(r.mc.current_state().position[1])
        assert np.all(np.diff(zs) <= 1e-12)  # straight back in, never further out
        assert zs[-1] == pytest.approx(0.1, abs=1e-9)
        assert abs(r.measured()[1] - 0.1) < 5e-3
    finally:
        r.close()
