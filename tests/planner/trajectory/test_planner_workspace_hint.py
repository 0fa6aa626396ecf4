"""The planner's workspace refusal: its face with the unit, and the mm / degree hint when the value fits so.

Truth: the workspace box of the default profile (TrajectoryPlanner.lo/hi) and planner.errors.unit_hint's
rule (|v| >= 1 and v/1000 m or v deg inside the range)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.model.kinematics import HitchModel
from planner.trajectory import MotionState, PlanError, TrajectoryPlanner


@pytest.fixture(scope="module")
def tp():
    return TrajectoryPlanner(HitchModel.from_profile())


def test_a_goal_in_mm_gets_the_hint_and_the_unit_of_the_face(tp):
    """The old message was 'goal.z = 250.0000 m is above the workspace (workspace:z:max = 0.3117)'."""
    p = np.array([0.0, 250.0, 0.0, 0.0])
    with pytest.raises(PlanError) as exc:
        tp.check_in_workspace(p)
    msg = str(exc.value)
    assert f"(workspace:z:max = {tp.hi[1]:.4f} m)" in msg and "did you mean mm? 250 mm = 0.25 m" in msg, msg


def test_an_angle_in_degrees_gets_the_hint_and_a_plain_miss_none(tp):
    with pytest.raises(PlanError, match=r"did you mean degrees\? 2 deg") as exc:
        tp.check_in_workspace(np.array([0.0, 0.0, 2.0, 0.0]))
    assert f"(workspace:roll:max = {tp.hi[2]:.4f} rad)" in str(exc.value)
    with pytest.raises(PlanError) as exc:
        tp.check_in_workspace(np.array([0.0, tp.hi[1] + 0.05, 0.0, 0.0]))  # 5 cm too high: no unit mix-up
    assert "did you mean" not in str(exc.value) and math.isfinite(tp.hi[1])


def test_a_lateral_goal_beyond_the_workspace_is_left_or_right_of_it(model):
    """x is lateral (+x the driver's left): "goal.x = 0.1 m is above the workspace" read as a height (a new user's
    and a library user's report); z, roll and pitch stay above / below."""
    tp = TrajectoryPlanner(model)
    start = MotionState.at_rest(model.neutral_pose.controlled())
    for goal, words in (
        ({"x": 0.1}, "goal.x = 0.1000 m is left of the workspace (workspace:x:max"),
        ({"x": -0.1}, "goal.x = -0.1000 m is right of the workspace (workspace:x:min"),
        ({"z": 0.5}, "goal.z = 0.5000 m is above the workspace (workspace:z:max"),
    ):
        with pytest.raises(PlanError) as e:
            tp.plan_move(start, goal)
        assert words in str(e.value), str(e.value)
