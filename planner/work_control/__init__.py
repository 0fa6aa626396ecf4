"""Work control of a soil-engaging implement: position, draft, mixed and float control (with optional
slip limiting) choosing the z setpoint a track session follows. Pure: no bridge imports."""

from planner.work_control.controller import (
    FLOAT_DEAD_BAND_M,
    MODES,
    WorkController,
    WorkSettings,
    WorkSettingsError,
    WorkStatus,
)

__all__ = ["FLOAT_DEAD_BAND_M", "MODES", "WorkController", "WorkSettings", "WorkSettingsError", "WorkStatus"]
