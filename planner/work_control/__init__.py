"""Work control of a soil-engaging implement: position, draft, mixed and float control (with optional
slip limiting) choosing the z setpoint a track session follows. Pure: no bridge imports."""

from planner.work_control.controller import (
    DRAFT_SETPOINT_MAX_N,
    FLOAT_DEAD_BAND_M,
    MODES,
    WorkController,
    WorkSettings,
    WorkSettingsError,
    WorkStatus,
)

__all__ = [
    "DRAFT_SETPOINT_MAX_N",
    "FLOAT_DEAD_BAND_M",
    "MODES",
    "WorkController",
    "WorkSettings",
    "WorkSettingsError",
    "WorkStatus",
]
