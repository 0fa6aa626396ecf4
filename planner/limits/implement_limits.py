"""Per-implement limits the guard enforces: upper height, lowering speed, transport lock.

Pure checks on arrays of samples (no state, no I/O); :class:`planner.limits.guard.Guard` calls them.

* **Upper height limit** ``upper_height_m`` [m] (tool point T, tractor frame z): a planned sample
  above it is refused, naming :data:`UPPER_HEIGHT_LIMIT`; a plan that starts above it (the limit
  was just lowered) may only go down (no sample above ``max(limit, start z)``). Jog rates upward
  are clipped so the height ``jog_horizon`` seconds ahead stays at or below the limit.
* **Lowering speed limit** ``lowering_speed_m_s`` [m/s]: a bound on the downward z velocity of
  every planned sample. Ruckig's velocity limits are symmetric, so a plan that descends faster
  is slowed as a whole (a time dilation of the same path, as the end-stop zone does: the factor
  ``limit / fastest descent`` is a ``speed`` reason); jog rates are clipped to ``-limit``.
* **Track sessions** (:func:`track_bounds`): the follower's upper z face is lowered to the upper
  height limit (setpoints above it are clipped, flagged :data:`UPPER_HEIGHT_LIMIT`) and its downward
  z velocity bounded by the lowering speed limit (flagged :data:`LOWERING_SPEED_LIMIT`).
* **Transport lock** ``transport_locked``: every motion but stop is refused while it is set
  (checked by the motion controller, code ``locked``). It damps nothing: transport mode has no
  active damping of the implement's oscillations yet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.errors import HitchInputError
from planner.trajectory.track import TrackBounds

__all__ = [
    "UPPER_HEIGHT_LIMIT",
    "LOWERING_SPEED_LIMIT",
    "TRANSPORT_LOCK",
    "UPPER_HEIGHT_RANGE_M",
    "LOWERING_SPEED_RANGE_M_S",
    "ImplementLimits",
    "ImplementLimitError",
    "upper_height_violation",
    "lowering_speed_factor",
    "clip_jog_z_rate",
    "track_bounds",
]

#: the names the guard's reasons carry
UPPER_HEIGHT_LIMIT = "implement upper height limit"
LOWERING_SPEED_LIMIT = "implement lowering speed limit"
TRANSPORT_LOCK = "implement transport lock"
#: allowed ranges of the settings (z of the tool point in the tractor frame [m]; speed [m/s])
UPPER_HEIGHT_RANGE_M = (-1.0, 2.0)
LOWERING_SPEED_RANGE_M_S = (0.005, 2.0)
_TOL_M = 1e-9


class ImplementLimitError(HitchInputError):
    """An implement limit outside its allowed range; names the field."""


@dataclass(frozen=True)
class ImplementLimits:
    """The limits of one implement (None: no such limit)."""

    upper_height_m: float | None = None
    lowering_speed_m_s: float | None = None
    transport_locked: bool = False

    def __post_init__(self) -> None:
        for name, rng, unit in (
            ("upper_height_m", UPPER_HEIGHT_RANGE_M, "m"),
            ("lowering_speed_m_s", LOWERING_SPEED_RANGE_M_S, "m/s"),
        ):
            v = getattr(self, name)
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ImplementLimitError(f"{name} must be a finite number [{unit}] or absent, got {v!r}")
            if not rng[0] <= v <= rng[1]:
                raise ImplementLimitError(f"{name} = {v!r} {unit} is outside the allowed range [{rng[0]}, {rng[1]}]")
            object.__setattr__(self, name, float(v))
        if not isinstance(self.transport_locked, bool):
            raise ImplementLimitError(f"transport_locked must be true or false, got {self.transport_locked!r}")

    def to_json(self) -> dict[str, float | bool | None]:
        return {
            "upper_height_m": self.upper_height_m,
            "lowering_speed_m_s": self.lowering_speed_m_s,
            "transport_locked": self.transport_locked,
        }


def upper_height_violation(z: np.ndarray, limits: ImplementLimits) -> tuple[int, float] | None:
    """(the highest sample, its z [m]) of heights ``z`` (N,) above the upper height limit, or None; a NaN
    height counts as above (the first one is given).

    The highest, not the first: a goto to 300 mm under a 200 mm limit was refused "would be 200.6 mm … at
    t = 0.96 s", the first sample over it, not the goal asked (a terminal trial). A plan starting above the
    limit is allowed to stay at or below its start height (it may only descend towards the limit)."""
    upper = limits.upper_height_m
    if upper is None or len(z) == 0:
        return None
    bound = max(upper, float(z[0])) + _TOL_M
    with np.errstate(invalid="ignore"):
        above = ~(z <= bound)  # NaN counts as above
    if not above.any():
        return None
    nan = np.flatnonzero(np.isnan(z))
    k = int(nan[0]) if nan.size else int(np.argmax(z))
    return k, float(z[k])


def lowering_speed_factor(vz: np.ndarray, limits: ImplementLimits) -> tuple[int, float, float] | None:
    """(sample of the fastest descent, factor = limit / its speed, its speed [m/s]) when z velocities
    ``vz`` (N,) [m/s] descend faster than the lowering speed limit, else None."""
    limit = limits.lowering_speed_m_s
    if limit is None or len(vz) == 0:
        return None
    k = int(np.argmin(vz))
    down = -float(vz[k])
    if not down > limit + 1e-12:
        return None
    return k, limit / down, down


def clip_jog_z_rate(z_now: float, vz: float, horizon_s: float, limits: ImplementLimits) -> tuple[float, str | None]:
    """A jog's z rate [m/s] within the implement's limits: at least ``-lowering_speed_m_s``, and
    upward at most what reaches the upper height limit ``horizon_s`` ahead (0 at or above it).
    Returns the rate and the name of the limit that clipped it (None: unchanged)."""
    if limits.lowering_speed_m_s is not None and vz < -limits.lowering_speed_m_s:
        return -limits.lowering_speed_m_s, LOWERING_SPEED_LIMIT
    upper = limits.upper_height_m
    if upper is not None and vz > 0.0:
        cap = max(0.0, (upper - z_now) / max(horizon_s, 1e-3))
        if vz > cap:
            return cap, UPPER_HEIGHT_LIMIT
    return vz, None


def track_bounds(limits: ImplementLimits) -> TrackBounds:
    """The bounds a track session follows for ``limits``: its upper z face at the upper height limit,
    its downward z velocity at most the lowering speed limit, named as the guard names them."""
    return TrackBounds(
        z_max_m=limits.upper_height_m,
        z_descent_m_s=limits.lowering_speed_m_s,
        z_max_name=UPPER_HEIGHT_LIMIT,
        z_descent_name=LOWERING_SPEED_LIMIT,
    )
