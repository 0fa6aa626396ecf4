"""The link's check of an actuator reference before it is streamed: every hard limit, then the AD counts.

A reference (five actuators in SI, lift [rad], the others [m]) is refused when a value is not finite, the
mechanism cannot take it (no closure), an actuator leaves its stroke or a mechanism feature (top-link
angles, lower span, …) its hard limit, or its AD counts leave the sensor's range; the refusal names the limit,
the value and the bound. :class:`~bridge.link.can_link.CanLink` checks every reference with it before it is
sent (the service's own previews use the link's, under its lock); a planning process, a service whose core runs
in another process and ``hitch plan`` check a preview's count approach with one of their own, on their own
model (models are not thread-safe), so a preview ends as the goto would.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from bridge.isobus.codec import PositionCounts
from bridge.link.state import ReferenceRefused
from planner.model.hard_limits import HardLimits
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorRangeError, SensorScaling
from planner.model.types import ACTUATOR_NAMES, KinematicsError

__all__ = ["ReferenceCheck"]


class ReferenceCheck:
    """The hard-limit and count check of references for ``model`` (its profile's limits and AD maps).

    Calling it with the actuators (SI, actuator order) returns their 0xFF21 counts, or raises
    :class:`~bridge.link.state.ReferenceRefused` naming the limit, the value and the bound."""

    def __init__(self, model: HitchModel) -> None:
        self.model = model
        self.scaling = SensorScaling(model.profile)
        self.hard = HardLimits.from_model(model)
        # the last values accepted and their counts: the check is a pure function of the values, and a caller
        # often checks the same reference twice (the controller before sending it, the link as it sends it)
        self._accepted: tuple[bytes, PositionCounts] | None = None

    def __call__(self, actuators: ArrayLike) -> PositionCounts:
        try:
            q = np.asarray(actuators, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ReferenceRefused(f"reference must be 5 numbers {ACTUATOR_NAMES}, got {actuators!r}") from None
        key = q.tobytes()
        accepted = self._accepted
        if accepted is not None and accepted[0] == key:
            return accepted[1]
        counts = self._check(q)
        self._accepted = (key, counts)
        return counts

    def _check(self, q: np.ndarray) -> PositionCounts:
        if q.size != 5:
            raise ReferenceRefused(f"reference needs 5 values {ACTUATOR_NAMES}, got {q.size}")
        for name, v in zip(ACTUATOR_NAMES, q, strict=True):
            if not math.isfinite(v):
                raise ReferenceRefused(f"reference.{name} must be finite, got {v}")
        try:
            feats, _ = self.model.features(q)
        except KinematicsError as exc:
            raise ReferenceRefused(f"reference refused: the mechanism cannot take it ({exc})") from None
        bad = self.hard.violations(q, feats, tol=1e-9)
        if bad:
            raise ReferenceRefused("reference refused: " + "; ".join(self._describe(n, q, feats) for n in bad))
        try:
            counts = self.scaling.to_counts(q)
        except SensorRangeError as exc:
            raise ReferenceRefused(f"reference refused: {exc}") from None
        return PositionCounts(*(int(c) for c in counts))

    def _describe(self, name: str, q: np.ndarray, feats: np.ndarray) -> str:
        h = self.hard
        if name.startswith("stroke:"):
            _, act, side = name.split(":")
            i = ACTUATOR_NAMES.index(act)
            unit = "rad" if act == "lift" else "m"
            bound = h.actuator_lower[i] if side == "min" else h.actuator_upper[i]
            return f"{name} ({act} = {q[i]:.4f} {unit}, limit {bound:.4f} {unit})"
        for k, idx in enumerate(h.feature_index):
            for names, bounds in ((h.names_lower, h.feature_lower), (h.names_upper, h.feature_upper)):
                if names[k] == name:
                    return f"{name} (value {feats[idx]:.4f}, limit {bounds[k]:.4f})"
        return name
