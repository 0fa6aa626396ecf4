"""The hitch model: value types, exact forward and inverse kinematics, hard limits and their names,
reachability and the restricted workspace, AD sensor scaling (SI units throughout).

Names load lazily: ``import planner.model.types`` imports no CasADi.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from planner.model.angle_maps import AngleMaps
    from planner.model.exact_inverse import ExactInverse
    from planner.model.fast_function import FastFunction
    from planner.model.hard_limits import FEATURE_LIMIT_ROWS, STROKE_NAMES, WORKSPACE_NAMES, HardLimits
    from planner.model.kinematics import FEATURE_NAMES, POINT_NAMES, HitchModel, SymbolicModel
    from planner.model.limit_names import LimitName, LimitNameError
    from planner.model.sensors import AD_COUNTS_MAX, SensorRangeError, SensorScaling
    from planner.model.types import (
        ACTUATOR_NAMES,
        ACTUATOR_UNITS,
        CONTROLLED_POSE_NAMES,
        CONTROLLED_POSE_UNITS,
        POSE_NAMES,
        Actuators,
        HitchState,
        KinematicsError,
        ModelInputError,
        Pose,
    )
    from planner.model.workspace import FitResult, Reachability, box_grid, fit_restricted_box

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(
        (
            "ACTUATOR_NAMES",
            "ACTUATOR_UNITS",
            "POSE_NAMES",
            "CONTROLLED_POSE_NAMES",
            "CONTROLLED_POSE_UNITS",
            "Actuators",
            "Pose",
            "HitchState",
            "KinematicsError",
            "ModelInputError",
        ),
        "planner.model.types",
    ),
    **dict.fromkeys(("HitchModel", "SymbolicModel", "FEATURE_NAMES", "POINT_NAMES"), "planner.model.kinematics"),
    "ExactInverse": "planner.model.exact_inverse",
    "AngleMaps": "planner.model.angle_maps",
    **dict.fromkeys(
        ("HardLimits", "FEATURE_LIMIT_ROWS", "STROKE_NAMES", "WORKSPACE_NAMES"), "planner.model.hard_limits"
    ),
    **dict.fromkeys(("LimitName", "LimitNameError"), "planner.model.limit_names"),
    **dict.fromkeys(("Reachability", "FitResult", "fit_restricted_box", "box_grid"), "planner.model.workspace"),
    **dict.fromkeys(("SensorScaling", "SensorRangeError", "AD_COUNTS_MAX"), "planner.model.sensors"),
    "FastFunction": "planner.model.fast_function",
}

__all__ = [
    "ACTUATOR_NAMES",
    "ACTUATOR_UNITS",
    "POSE_NAMES",
    "CONTROLLED_POSE_NAMES",
    "CONTROLLED_POSE_UNITS",
    "Actuators",
    "Pose",
    "HitchState",
    "KinematicsError",
    "ModelInputError",
    "HitchModel",
    "SymbolicModel",
    "FEATURE_NAMES",
    "POINT_NAMES",
    "ExactInverse",
    "AngleMaps",
    "HardLimits",
    "FEATURE_LIMIT_ROWS",
    "STROKE_NAMES",
    "WORKSPACE_NAMES",
    "LimitName",
    "LimitNameError",
    "Reachability",
    "FitResult",
    "fit_restricted_box",
    "box_grid",
    "SensorScaling",
    "SensorRangeError",
    "AD_COUNTS_MAX",
    "FastFunction",
]

if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports("planner.model", globals(), _SOURCES)
