"""Jerk-limited, time-synchronised trajectories between implement poses (issue 4)."""

from planner.trajectory.actuator_limits import ActuatorLimits
from planner.trajectory.jog import JOG_FIELDS, JogController, JogOutput
from planner.trajectory.joint_space import JointSamples, plan_joint_move
from planner.trajectory.plan import MotionState, Plan, PlanError, Setpoints, Violation, sample_plan, verify_setpoints
from planner.trajectory.planner import TrajectoryPlanner, Waypoint
from planner.trajectory.pose_limits import PoseLimits, box_limits, straight_line_limits

__all__ = [
    "ActuatorLimits",
    "MotionState",
    "Plan",
    "PlanError",
    "Setpoints",
    "Violation",
    "sample_plan",
    "verify_setpoints",
    "TrajectoryPlanner",
    "Waypoint",
    "JogController",
    "JogOutput",
    "JOG_FIELDS",
    "JointSamples",
    "plan_joint_move",
    "PoseLimits",
    "box_limits",
    "straight_line_limits",
]
