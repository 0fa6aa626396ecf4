"""Jerk-limited, time-synchronised trajectories between implement poses (Ruckig in pose space),
sampled into verified actuator setpoints; jog; track (streamed setpoints); joint-space moves; braking
from a moving state with the actuators' real limits; the ideal follower (the physical tracking limit)."""

from planner.trajectory.actuator_limits import ActuatorLimits, ActuatorLimitsError
from planner.trajectory.braking import StopProbe, braking_limits
from planner.trajectory.count_approach import (
    CountApproach,
    CountApproachError,
    build_count_approach,
    count_approach_for,
)
from planner.trajectory.final_approach import ApproachVia, final_approach_via
from planner.trajectory.ideal_follower import (
    IdealFollow,
    IdealFollower,
    IdealGain,
    ideal_bandwidth_hz,
    ideal_follow,
    ideal_sine_gain,
)
from planner.trajectory.jog import JOG_FIELDS, JogController, JogError, JogOutput
from planner.trajectory.joint_space import JointSamples, plan_joint_move
from planner.trajectory.plan import (
    MotionState,
    Plan,
    PlanError,
    Setpoints,
    TrajectoryInputError,
    Violation,
    sample_plan,
    verify_setpoints,
)
from planner.trajectory.planner import TrajectoryPlanner, Waypoint
from planner.trajectory.pose_limits import PoseLimits, box_limits, straight_line_limits
from planner.trajectory.track import (
    SeqFilter,
    TrackError,
    TrackFollower,
    TrackInputError,
    TrackOutput,
    TrackSetpoint,
    TrackStateError,
)

__all__ = [
    "ActuatorLimits",
    "ActuatorLimitsError",
    "ApproachVia",
    "CountApproach",
    "CountApproachError",
    "build_count_approach",
    "count_approach_for",
    "final_approach_via",
    "MotionState",
    "Plan",
    "PlanError",
    "TrajectoryInputError",
    "Setpoints",
    "Violation",
    "sample_plan",
    "verify_setpoints",
    "TrajectoryPlanner",
    "Waypoint",
    "JogController",
    "JogError",
    "JogOutput",
    "JOG_FIELDS",
    "JointSamples",
    "plan_joint_move",
    "PoseLimits",
    "box_limits",
    "straight_line_limits",
    "StopProbe",
    "braking_limits",
    "TrackFollower",
    "TrackSetpoint",
    "TrackOutput",
    "TrackError",
    "TrackInputError",
    "TrackStateError",
    "SeqFilter",
    "IdealFollower",
    "IdealFollow",
    "IdealGain",
    "ideal_sine_gain",
    "ideal_bandwidth_hz",
    "ideal_follow",
]
