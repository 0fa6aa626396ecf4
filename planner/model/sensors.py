"""Sensor scaling: actuators (SI) ↔ 10-bit AD counts (thesis tables 3-1 and 3-2).

Each actuator's reading is linear between (stroke min, counts_min) and (stroke max,
counts_max). Readings outside the calibrated span are reported with a
:class:`SensorRangeError`, never silently clamped.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from planner.errors import HitchInputError
from planner.model.types import ACTUATOR_NAMES, ModelInputError
from planner.profiles.hitch import Profile

__all__ = ["SensorRangeError", "SensorScaling", "AD_COUNTS_MAX"]

#: Largest raw value of a 10-bit AD converter.
AD_COUNTS_MAX = 1023


class SensorRangeError(HitchInputError):
    """A reading or command outside the calibrated span; names the actuator, value and span."""


class SensorScaling:
    """Linear AD calibration of the five actuators of a profile."""

    def __init__(self, profile: Profile):
        specs = [profile.actuator(n) for n in ACTUATOR_NAMES]
        self.si_min = np.array([s.min for s in specs])
        self.si_max = np.array([s.max for s in specs])
        self.counts_min = np.array([s.counts_min for s in specs], dtype=float)
        self.counts_max = np.array([s.counts_max for s in specs], dtype=float)
        #: SI units per count [m/count or rad/count]
        self.resolution = (self.si_max - self.si_min) / (self.counts_max - self.counts_min)

    def counts_of(self, q: ArrayLike) -> np.ndarray:
        """The exact (unrounded) counts [float] of actuators ``q`` (SI), unchecked against the span (not 5 numbers:
        :class:`ModelInputError`)."""
        return self.counts_min + (_five(q, "actuators") - self.si_min) / self.resolution

    def to_counts(self, q: ArrayLike, *, tolerance_counts: float = 0.5) -> np.ndarray:
        """Nearest integer counts of actuators ``q`` (SI); raises if beyond the calibrated span."""
        counts = self.counts_of(q)
        self._check(counts, tolerance_counts, "command")
        return np.clip(np.rint(counts), self.counts_min, self.counts_max).astype(int)

    def to_si(self, counts: ArrayLike, *, tolerance_counts: float = 0.0) -> np.ndarray:
        """Actuators (SI) from raw counts; raises if a reading lies outside the calibrated span."""
        c = _five(counts, "counts")
        self._check(c, tolerance_counts, "reading")
        return self.si_min + (c - self.counts_min) * self.resolution

    def _check(self, counts: np.ndarray, tol: float, what: str) -> None:
        bad = [
            f"{n} {what} {c:.1f} counts outside the calibrated span [{lo:.0f}, {hi:.0f}]"
            for n, c, lo, hi in zip(ACTUATOR_NAMES, counts, self.counts_min, self.counts_max, strict=True)
            if not (lo - tol <= c <= hi + tol)
        ]
        if bad:
            raise SensorRangeError("; ".join(bad))


def _five(values: ArrayLike, what: str) -> np.ndarray:
    """``values`` as 5 floats (order ACTUATOR_NAMES), else :class:`ModelInputError` naming ``what`` (3 values
    failed as numpy's "cannot reshape array of size 3 into shape (5,)")."""
    try:
        v = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        v = np.empty(0)
    if v.size != len(ACTUATOR_NAMES):
        raise ModelInputError(f"{what} must be 5 numbers ({', '.join(ACTUATOR_NAMES)}), got {values!r}")
    return v
