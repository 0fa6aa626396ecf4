"""Per-actuator velocity, acceleration and jerk limits from the valves.

The fastest a cylinder moves is its valve's full flow: identified gain × maximum
command × valve multiplier (thesis tables 3-3, 3-4), in AD counts per second, converted
to SI through the AD calibration (tables 3-1, 3-2). The direction with the smaller gain
bounds both directions. A fraction of it is left to the unit controllers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.errors import HitchInputError
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES
from planner.profiles.hitch import Profile

__all__ = ["ActuatorLimits", "ActuatorLimitsError", "VALVE_COMMAND_MAX"]

#: Largest valve command of the thesis ECU (commands range −254 … 254).
VALVE_COMMAND_MAX = 254


#: unit of each field for the lift (an angle) and for the cylinders (lengths)
_UNITS = {"velocity": ("rad/s", "m/s"), "acceleration": ("rad/s²", "m/s²"), "jerk": ("rad/s³", "m/s³")}


class ActuatorLimitsError(HitchInputError):
    """Actuator limits that cannot be used (not 5 values, not a positive finite number); names the field."""


@dataclass(frozen=True)
class ActuatorLimits:
    """Limits in actuator units per s, s², s³ (rad for lift, m for the cylinders), order ACTUATOR_NAMES.

    Each field: 5 numbers in (0, inf), kept as float arrays; else :class:`ActuatorLimitsError` naming the field
    and the actuator (3 values failed at the planner as numpy's broadcast error, and a negative, zero or NaN
    limit was taken)."""

    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray

    def __post_init__(self) -> None:
        for name, (lift_unit, unit) in _UNITS.items():
            given = getattr(self, name)
            try:
                v = np.asarray(given, dtype=float)
            except (TypeError, ValueError):
                raise ActuatorLimitsError(
                    f"{name} must be 5 numbers ({', '.join(ACTUATOR_NAMES)}), got {given!r}"
                ) from None
            if v.shape != (len(ACTUATOR_NAMES),):
                raise ActuatorLimitsError(
                    f"{name} must be 5 numbers ({', '.join(ACTUATOR_NAMES)}), got shape {v.shape}"
                )
            for n, x in zip(ACTUATOR_NAMES, v.tolist(), strict=True):
                if not (math.isfinite(x) and x > 0.0):
                    u = lift_unit if n == "lift" else unit
                    raise ActuatorLimitsError(f"{name}.{n} must lie within (0, inf) {u}, got {x!r}")
            object.__setattr__(self, name, v)

    @classmethod
    def from_profile(cls, profile: Profile) -> ActuatorLimits:
        res = SensorScaling(profile).resolution
        mo = profile.motion
        flow_counts = np.array(
            [
                min(profile.actuator(n).kv_pos, profile.actuator(n).kv_neg)
                * VALVE_COMMAND_MAX
                * profile.actuator(n).valve_multiplier
                for n in ACTUATOR_NAMES
            ]
        )
        v = mo.velocity_fraction * flow_counts * res
        a = v / mo.acceleration_time
        return cls(velocity=v, acceleration=a, jerk=a / mo.jerk_time)

    def scaled(self, factor: float) -> ActuatorLimits:
        """Velocity × factor, acceleration × factor², jerk × factor³ (a slower copy of the same motion);
        ``factor`` in (0, inf), else :class:`ActuatorLimitsError` (0 and −1 gave zero and negative limits)."""
        if (
            isinstance(factor, bool)
            or not isinstance(factor, (int, float, np.integer, np.floating))
            or not 0 < factor < math.inf
        ):
            raise ActuatorLimitsError(f"scaled: factor must be a number within (0, inf), got {factor!r}")
        return ActuatorLimits(self.velocity * factor, self.acceleration * factor**2, self.jerk * factor**3)

    def as_dict(self) -> dict[str, dict[str, float]]:
        return {
            "velocity": dict(zip(ACTUATOR_NAMES, map(float, self.velocity), strict=True)),
            "acceleration": dict(zip(ACTUATOR_NAMES, map(float, self.acceleration), strict=True)),
            "jerk": dict(zip(ACTUATOR_NAMES, map(float, self.jerk), strict=True)),
        }
