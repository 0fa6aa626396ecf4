"""Safety margin near the hard limits: no actuator reaches an end stop at full speed (seed 003).

Within the last ``zone`` fraction of its stroke an actuator moving towards the end may
move at most v_max · sqrt(d / zone_length), d the distance left to the end stop: a
constant-deceleration approach that arrives at zero speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["EndStopZone"]


@dataclass(frozen=True)
class EndStopZone:
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray  # full-speed limits (actuator units/s)
    zone_fraction: float = 0.05  # of each stroke

    def allowed_speed(self, q: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """Largest |q̇_i| allowed at q when moving with the sign of ``direction`` (0 = not moving)."""
        zone = self.zone_fraction * (self.upper - self.lower)
        dist = np.where(direction > 0, self.upper - q, np.where(direction < 0, q - self.lower, np.inf))
        frac = np.sqrt(np.clip(dist / zone, 0.0, 1.0))
        return self.velocity * frac

    def speed_factor(self, q: np.ndarray, qdot: np.ndarray) -> tuple[float, int | None]:
        """Largest factor ≤ 1 by which ``qdot`` must be scaled at ``q``, and the actuator that binds."""
        allow = self.allowed_speed(q, np.sign(qdot))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(np.abs(qdot) > 1e-12, allow / np.abs(qdot), np.inf)
        i = int(np.argmin(ratio))
        return (float(min(1.0, ratio[i])), i if ratio[i] < 1.0 else None)
