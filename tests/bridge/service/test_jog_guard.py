"""A jog is judged by the stability guard at the rates it can run (its speed limits), whatever rate was asked.

Truth: the guard's own verdict on the jog at its speed limit (``Guard.check_jog``); a rate asked beyond the
limit must get the same verdict, since the jog runs at the limit either way.
"""

from __future__ import annotations

import numpy as np
import pytest

from bridge.service.motion.types import JogMotion
from planner.limits.guard import Guard
from planner.limits.tractor import ImplementRecord
from planner.model.kinematics import HitchModel
from planner.profiles.hitch import load_profile
from planner.trajectory import JogController, MotionState, TrajectoryPlanner


@pytest.fixture(scope="module")
def planner():
    return TrajectoryPlanner(HitchModel(load_profile()))


def _jog(planner, z: float) -> tuple[Guard, JogMotion]:
    # an operator's trial: 2500 kg with its centre of mass 1.2 m behind the hitch; a goto to z = 0.12 m was refused
    # ("esm would be 76.32 J (threshold 2000 J)")
    guard = Guard(planner, implement=ImplementRecord("hv", "2", 2500.0, (0.0, 1.2, 0.3)))
    start = MotionState.at_rest([0.0, z, 0.0, 0.0])
    return guard, JogMotion(1, JogController(planner, start), np.zeros(4), 1.0)


@pytest.mark.parametrize("asked_vz", [1.0, 0.2])
def test_a_lift_jog_asked_beyond_its_speed_limit_gets_the_verdict_of_its_real_speed(planner, asked_vz):
    """The trial: lifting at 0.02 m/s was refused (esm ahead), at 1 m/s the same jog lifted the implement 124 mm
    ("guard": "scaled", only the lift's speed named): judged 1 m ahead at the workspace face, where the margin
    passed, not at the speed it ran."""
    guard, jog = _jog(planner, 0.0)
    v_max = jog.jog.limits.velocity[1]
    assert asked_vz > v_max
    _, at_limit = guard.check_jog(jog.jog.state, np.array([0.0, v_max, 0.0, 0.0]))
    assert at_limit.action == "refused" and "esm" in {r.measure for r in at_limit.reasons}, at_limit
    accepted = jog.refresh(guard, np.array([0.0, asked_vz, 0.0, 0.0]), 1.0)
    assert accepted.decision.action == "refused", accepted
    assert {r.measure for r in accepted.decision.reasons} == {r.measure for r in at_limit.reasons}
    for _ in range(25):  # half a second of control cycles: the hitch stays where it was
        out, _ = jog.step(guard)
    assert abs(out.state.position[1]) < 1e-9 and not np.any(out.state.velocity)
    # lowering improves the margin: allowed at any rate asked, run at the jog's speed limit
    accepted = jog.refresh(guard, np.array([0.0, -asked_vz, 0.0, 0.0]), 1.0)
    assert accepted.decision.action != "refused", accepted


def test_a_lift_jog_asked_beyond_its_speed_limit_is_slowed_by_a_caution_as_at_its_real_speed(planner):
    """The trial: with the 1500 kg power harrow at z = −0.1 m a lift jog at the speed limit was slowed to 0.8 for
    front_axle_load; asked at 1 m/s it ran at full speed (judged at the face, front_axle_load not named)."""
    from planner.limits.tractor import load_tractor_profile

    guard = Guard(planner, implement=load_tractor_profile().implement("cat2-power-harrow-1500"))
    jog = JogMotion(1, JogController(planner, MotionState.at_rest([0.0, -0.1, 0.0, 0.0])), np.zeros(4), 1.0)
    v_max = jog.jog.limits.velocity[1]
    _, at_limit = guard.check_jog(jog.jog.state, np.array([0.0, v_max, 0.0, 0.0]))
    assert at_limit.action == "scaled" and at_limit.speed_factor == pytest.approx(0.8), at_limit
    assert "front_axle_load" in {r.measure for r in at_limit.reasons}
    accepted = jog.refresh(guard, np.array([0.0, 1.0, 0.0, 0.0]), 1.0)
    assert accepted.decision.speed_factor == pytest.approx(0.8), accepted
    assert {r.measure for r in accepted.decision.reasons} == {r.measure for r in at_limit.reasons}
    assert accepted.limited.get("z+") == "velocity:z"  # the speed asked beyond the limit is still said
