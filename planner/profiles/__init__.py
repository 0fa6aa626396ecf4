"""Hitch profiles: the strict schema of a hitch description (geometry, implement categories,
actuators with their sensor calibration and valve dynamics, limits, workspace, motion,
stability settings), loading by built-in name or TOML path, and the shared TOML loading of
arm and tractor profiles (:mod:`planner.profiles.loader`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from planner.profiles.hitch import (
        THESIS_CONTROLLER_A,
        ActuatorSpec,
        Category,
        Profile,
        available_profiles,
        load_profile,
        profile_from_dict,
    )
    from planner.profiles.loader import ProfileError

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(
        (
            "Profile",
            "ActuatorSpec",
            "Category",
            "THESIS_CONTROLLER_A",
            "load_profile",
            "available_profiles",
            "profile_from_dict",
        ),
        "planner.profiles.hitch",
    ),
    "ProfileError": "planner.profiles.loader",
}

__all__ = [
    "Profile",
    "ActuatorSpec",
    "Category",
    "THESIS_CONTROLLER_A",
    "load_profile",
    "available_profiles",
    "profile_from_dict",
    "ProfileError",
]

if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports("planner.profiles", globals(), _SOURCES)
