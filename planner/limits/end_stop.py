"""Safety margin near the hard limits: no actuator reaches an end stop at full speed (seed 003).

Within the last ``zone`` fraction of its stroke an actuator moving towards the end may
move at most v_max · sqrt(d / zone_length), d the distance left to the end stop: a
constant-deceleration approach that arrives at zero speed.
"""

from __future__ import annotations

import math
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

    def in_zone(self, q: np.ndarray, qdot: np.ndarray, i: int) -> bool:
        """Whether actuator ``i`` at ``q`` moving with the sign of ``qdot`` is inside its end-stop zone (closer
        to the stroke end it moves to than ``zone_fraction`` of its stroke): there :meth:`speed_factor` slows
        it for the end stop; outside, a factor below 1 is its plain velocity limit."""
        qi, qdi = float(np.asarray(q, float)[i]), float(np.asarray(qdot, float)[i])
        if not (math.isfinite(qi) and math.isfinite(qdi)):
            return True  # fail closed: :meth:`speed_factor` stops it, named for the end stop
        lo, hi = float(self.lower[i]), float(self.upper[i])
        dist = hi - qi if qdi > 0 else qi - lo
        return dist < self.zone_fraction * (hi - lo)

    def speed_factor(self, q: np.ndarray, qdot: np.ndarray) -> tuple[float, int | None]:
        """Largest factor ≤ 1 by which ``qdot`` must be scaled at ``q``, and the actuator that binds.

        Finite 1-D inputs are evaluated in Python floats (the jog check's path, once per guarded
        cycle): the same IEEE operations as :meth:`allowed_speed` and the ratio below, bit for bit
        (``sqrt`` is correctly rounded in both, the first smallest ratio binds as ``argmin`` picks
        it); anything else (NaN, other shapes) takes the array path. A non-finite position or rate binds with
        the factor 0 (fail closed: NaN compares false, so ``argmin`` and ``min(1, nan)`` read it as "no
        slow-down" before; a reviewer's reproduction).
        """
        ql, qdl = np.asarray(q, float).tolist(), np.asarray(qdot, float).tolist()
        if isinstance(ql, list) and isinstance(qdl, list) and len(ql) == len(qdl) == len(self.lower):
            if all(map(math.isfinite, ql)) and all(map(math.isfinite, qdl)):
                res = self._speed_factor_floats(ql, qdl)
                if res is not None:
                    return res
        return self._speed_factor_arrays(np.asarray(q, float), np.asarray(qdot, float))

    def _speed_factor_floats(self, q: list[float], qdot: list[float]) -> tuple[float, int | None] | None:
        """:meth:`speed_factor` in floats; None where a zone is empty (numpy's x / 0 there)."""
        lo, hi, vel = self.lower.tolist(), self.upper.tolist(), self.velocity.tolist()
        zf = self.zone_fraction
        best, best_i = math.inf, 0
        for k, (qk, qdk) in enumerate(zip(q, qdot, strict=True)):
            if not abs(qdk) > 1e-12:
                continue  # ratio inf
            dist = hi[k] - qk if qdk > 0 else qk - lo[k]
            zone = zf * (hi[k] - lo[k])
            if not zone > 0.0:
                return None
            frac = math.sqrt(min(max(dist / zone, 0.0), 1.0))
            ratio = vel[k] * frac / abs(qdk)
            if ratio < best:
                best, best_i = ratio, k
        return (float(min(1.0, best)), best_i if best < 1.0 else None)

    def _speed_factor_arrays(self, q: np.ndarray, qdot: np.ndarray) -> tuple[float, int | None]:
        bad = np.flatnonzero(~(np.isfinite(np.broadcast_to(q, np.shape(qdot))) & np.isfinite(qdot)))
        if bad.size:  # fail closed, naming the first actuator without a number
            return 0.0, int(bad[0])
        allow = self.allowed_speed(q, np.sign(qdot))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(np.abs(qdot) > 1e-12, allow / np.abs(qdot), np.inf)
        i = int(np.argmin(ratio))
        return (float(min(1.0, ratio[i])), i if ratio[i] < 1.0 else None)
