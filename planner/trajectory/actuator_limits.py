"""Per-actuator velocity, acceleration and jerk limits from the valves.

The fastest a cylinder moves is its valve's full flow: identified gain × maximum
command × valve multiplier (thesis tables 3-3, 3-4), in AD counts per second, converted
to SI through the AD calibration (tables 3-1, 3-2). The direction with the smaller gain
bounds both directions. A fraction of it is left to the unit controllers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES
from planner.profiles.hitch import Profile

__all__ = ["ActuatorLimits", "VALVE_COMMAND_MAX"]

#: Largest valve command of the thesis ECU (commands range −254 … 254).
VALVE_COMMAND_MAX = 254


@dataclass(frozen=True)
class ActuatorLimits:
    """Limits in actuator units per s, s², s³ (rad for lift, m for the cylinders), order ACTUATOR_NAMES."""

    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray

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
        """Velocity × factor, acceleration × factor², jerk × factor³ (a slower copy of the same motion)."""
        return ActuatorLimits(self.velocity * factor, self.acceleration * factor**2, self.jerk * factor**3)

    def as_dict(self) -> dict[str, dict[str, float]]:
        return {
            "velocity": dict(zip(ACTUATOR_NAMES, map(float, self.velocity), strict=True)),
            "acceleration": dict(zip(ACTUATOR_NAMES, map(float, self.acceleration), strict=True)),
            "jerk": dict(zip(ACTUATOR_NAMES, map(float, self.jerk), strict=True)),
        }
