"""Limits of the hitch and the tractor: the guard every motion passes through, tractor + implement
stability (axle loads, SSM, LSM, ESM, front ballast), tractor profiles, kinematic margins and the
end-stop zone. (The function :func:`planner.limits.kinematic_margin.kinematic_margin` shares its
module's name, so it is imported from there.)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from planner.limits.end_stop import EndStopZone
    from planner.limits.guard import Guard, GuardDecision, GuardedPlan, GuardReason, GuardRefusal
    from planner.limits.implement_limits import ImplementLimitError, ImplementLimits
    from planner.limits.kinematic_margin import DofMargin, KinematicMargin
    from planner.limits.stability import (
        EDGE_NAMES,
        AxleLoads,
        EnergyMargins,
        LoadCase,
        Measure,
        StabilityReport,
        StabilityThresholds,
        StabilityViolation,
        SupportMargins,
        axle_loads,
        build_load_case,
        energy_margins,
        evaluate_stability,
        gravity_direction,
        minimum_front_ballast,
        support_margins,
    )
    from planner.limits.stability_batch import MEASURE_NAMES, StabilityBatch, evaluate_stability_batch
    from planner.limits.tractor import (
        ISO730_CATEGORIES,
        STANDARD_GRAVITY,
        ImplementRecord,
        StabilityInputError,
        Tractor,
        TractorProfile,
        TractorProfileError,
        build_tractor,
        load_tractor_profile,
        tractor_profile_from_dict,
    )

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(("Guard", "GuardDecision", "GuardReason", "GuardRefusal", "GuardedPlan"), "planner.limits.guard"),
    **dict.fromkeys(
        (
            "EDGE_NAMES",
            "Measure",
            "LoadCase",
            "AxleLoads",
            "SupportMargins",
            "EnergyMargins",
            "StabilityThresholds",
            "StabilityViolation",
            "StabilityReport",
            "build_load_case",
            "axle_loads",
            "support_margins",
            "energy_margins",
            "gravity_direction",
            "minimum_front_ballast",
            "evaluate_stability",
        ),
        "planner.limits.stability",
    ),
    **dict.fromkeys(("MEASURE_NAMES", "StabilityBatch", "evaluate_stability_batch"), "planner.limits.stability_batch"),
    **dict.fromkeys(
        (
            "STANDARD_GRAVITY",
            "ISO730_CATEGORIES",
            "StabilityInputError",
            "TractorProfileError",
            "Tractor",
            "ImplementRecord",
            "TractorProfile",
            "build_tractor",
            "load_tractor_profile",
            "tractor_profile_from_dict",
        ),
        "planner.limits.tractor",
    ),
    **dict.fromkeys(("DofMargin", "KinematicMargin"), "planner.limits.kinematic_margin"),
    "EndStopZone": "planner.limits.end_stop",
    **dict.fromkeys(("ImplementLimits", "ImplementLimitError"), "planner.limits.implement_limits"),
}

__all__ = [
    "Guard",
    "GuardDecision",
    "GuardReason",
    "GuardRefusal",
    "GuardedPlan",
    "EDGE_NAMES",
    "Measure",
    "LoadCase",
    "AxleLoads",
    "SupportMargins",
    "EnergyMargins",
    "StabilityThresholds",
    "StabilityViolation",
    "StabilityReport",
    "build_load_case",
    "axle_loads",
    "support_margins",
    "energy_margins",
    "gravity_direction",
    "minimum_front_ballast",
    "evaluate_stability",
    "MEASURE_NAMES",
    "StabilityBatch",
    "evaluate_stability_batch",
    "STANDARD_GRAVITY",
    "ISO730_CATEGORIES",
    "StabilityInputError",
    "TractorProfileError",
    "Tractor",
    "ImplementRecord",
    "TractorProfile",
    "build_tractor",
    "load_tractor_profile",
    "tractor_profile_from_dict",
    "DofMargin",
    "KinematicMargin",
    "EndStopZone",
    "ImplementLimits",
    "ImplementLimitError",
]

if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports("planner.limits", globals(), _SOURCES)
