"""hitch-planner: motion planning for the 4-DOF advanced rear hitch of a tractor.

Exact kinematics (CasADi), IK as a constrained QP (OSQP), jerk-limited trajectories (Ruckig)
verified against every limit, and a guard for the limits and the tractor's stability. SI units
(m, rad, s, kg) everywhere. Plan and check a move::

    from planner import Guard, HitchModel, IKSolver, MotionState, Target, TrajectoryPlanner

    model = HitchModel.from_profile("thesis-t132")  # exact model, neutral pose, restricted workspace
    ik = IKSolver(model).solve(Target(x=0.0, z=model.neutral_pose.z + 0.1, roll=0.0, pitch=0.0))
    print(ik.status, ik.actuators)  # "ok" and the five actuators, or "limited" naming the limits
    guard = Guard(TrajectoryPlanner(model))  # limits, end stops and tractor stability
    start = MotionState.at_rest(model.neutral_pose.controlled())
    move = guard.plan(start, {"z": model.neutral_pose.z + 0.1})  # PlanError / GuardRefusal if not allowed
    print(move.decision.action, move.plan.duration, move.setpoints.actuators[-1])

Every error the planner raises on purpose derives from :class:`HitchError`; bad input also from
``ValueError`` (:class:`HitchInputError`). Names load lazily: ``import planner.errors`` imports
nothing heavy. Sub-packages: :mod:`planner.model`, :mod:`planner.profiles`, :mod:`planner.ik_qp`,
:mod:`planner.trajectory`, :mod:`planner.limits`, :mod:`planner.arm`, :mod:`planner.calibration` (commissioning),
:mod:`planner.work_control` (draft, mixed and float control).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from planner.errors import HitchError, HitchInputError
    from planner.ik_qp.hitch_ik import IKSolver
    from planner.ik_qp.result import IKResult, Target
    from planner.limits.guard import Guard, GuardDecision, GuardedPlan, GuardRefusal
    from planner.limits.stability import StabilityThresholds
    from planner.limits.tractor import load_tractor_profile
    from planner.model.exact_inverse import ExactInverse
    from planner.model.hard_limits import HardLimits
    from planner.model.kinematics import HitchModel
    from planner.model.limit_names import LimitName
    from planner.model.sensors import SensorRangeError, SensorScaling
    from planner.model.types import (
        ACTUATOR_NAMES,
        ACTUATOR_UNITS,
        CONTROLLED_POSE_NAMES,
        POSE_NAMES,
        Actuators,
        HitchState,
        KinematicsError,
        Pose,
    )
    from planner.model.workspace import Reachability, fit_restricted_box
    from planner.profiles.hitch import Profile, available_profiles, load_profile
    from planner.profiles.loader import ProfileError
    from planner.trajectory.actuator_limits import ActuatorLimits
    from planner.trajectory.jog import JogController
    from planner.trajectory.plan import MotionState, Plan, PlanError, Setpoints
    from planner.trajectory.planner import TrajectoryPlanner, Waypoint
    from planner.trajectory.track import TrackFollower

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(("HitchError", "HitchInputError"), "planner.errors"),
    **dict.fromkeys(("ACTUATOR_NAMES", "ACTUATOR_UNITS", "POSE_NAMES", "CONTROLLED_POSE_NAMES"), "planner.model.types"),
    **dict.fromkeys(("Actuators", "Pose", "HitchState", "KinematicsError"), "planner.model.types"),
    "HitchModel": "planner.model.kinematics",
    "ExactInverse": "planner.model.exact_inverse",
    "HardLimits": "planner.model.hard_limits",
    "LimitName": "planner.model.limit_names",
    **dict.fromkeys(("Reachability", "fit_restricted_box"), "planner.model.workspace"),
    **dict.fromkeys(("SensorScaling", "SensorRangeError"), "planner.model.sensors"),
    **dict.fromkeys(("Profile", "load_profile", "available_profiles"), "planner.profiles.hitch"),
    "ProfileError": "planner.profiles.loader",
    "IKSolver": "planner.ik_qp.hitch_ik",
    **dict.fromkeys(("Target", "IKResult"), "planner.ik_qp.result"),
    "ActuatorLimits": "planner.trajectory.actuator_limits",
    **dict.fromkeys(("MotionState", "Plan", "PlanError", "Setpoints"), "planner.trajectory.plan"),
    **dict.fromkeys(("TrajectoryPlanner", "Waypoint"), "planner.trajectory.planner"),
    "JogController": "planner.trajectory.jog",
    "TrackFollower": "planner.trajectory.track",
    **dict.fromkeys(("Guard", "GuardDecision", "GuardRefusal", "GuardedPlan"), "planner.limits.guard"),
    "StabilityThresholds": "planner.limits.stability",
    "load_tractor_profile": "planner.limits.tractor",
}

__all__ = [
    "HitchError",
    "HitchInputError",
    "ACTUATOR_NAMES",
    "ACTUATOR_UNITS",
    "POSE_NAMES",
    "CONTROLLED_POSE_NAMES",
    "Actuators",
    "Pose",
    "HitchState",
    "KinematicsError",
    "HitchModel",
    "ExactInverse",
    "HardLimits",
    "LimitName",
    "Reachability",
    "fit_restricted_box",
    "SensorScaling",
    "SensorRangeError",
    "Profile",
    "load_profile",
    "available_profiles",
    "ProfileError",
    "IKSolver",
    "Target",
    "IKResult",
    "ActuatorLimits",
    "MotionState",
    "Plan",
    "PlanError",
    "Setpoints",
    "TrajectoryPlanner",
    "Waypoint",
    "JogController",
    "TrackFollower",
    "Guard",
    "GuardDecision",
    "GuardRefusal",
    "GuardedPlan",
    "StabilityThresholds",
    "load_tractor_profile",
]


def _version() -> str:
    """The installed distribution's version, or the source tree's when not installed."""
    import importlib.metadata  # here: ~20 ms, paid only by who asks

    try:
        return importlib.metadata.version("hitch-planner")
    except importlib.metadata.PackageNotFoundError:
        return "0.1.0"


if TYPE_CHECKING:
    __version__: str
else:
    _getattr, __dir__ = lazy_exports("planner", globals(), _SOURCES)

    def __getattr__(name: str) -> Any:
        if name == "__version__":
            globals()[name] = value = _version()
            return value
        return _getattr(name)
