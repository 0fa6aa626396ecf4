"""Kinematic margin: time to the nearest limit at the current velocity.

For each limit the time is distance-to-limit / rate-towards-it (∞ when moving away or at
rest). Reported per controlled DOF (the workspace faces) and overall (workspace faces,
actuator strokes, top-link angles, ground clearance), with the limit's name
(:class:`~planner.model.limit_names.LimitName` spelling).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TypedDict

import numpy as np

from planner.model.hard_limits import STROKE_NAMES, WORKSPACE_NAMES, HardLimits
from planner.model.types import CONTROLLED_POSE_NAMES

__all__ = ["DofMargin", "KinematicMargin", "kinematic_margin"]


class DofMargin(TypedDict):
    """Margin of one controlled DOF: time to its nearest workspace face [s] (∞ at rest) and its name."""

    time_s: float
    limit: str


@dataclass(frozen=True)
class KinematicMargin:
    time_s: float  # overall [s], ∞ at rest
    limit: str  # the limit that would be reached first ("" at rest)
    per_dof: dict[str, DofMargin]  # "x" → {"time_s", "limit"}

    def to_json(self) -> dict:
        def t(v: float) -> float | None:
            return None if math.isinf(v) else v

        return {
            "time_s": t(self.time_s),
            "limit": self.limit,
            "per_dof": {k: {"time_s": t(v["time_s"]), "limit": v["limit"]} for k, v in self.per_dof.items()},
        }


def _time(dist: float, rate: float) -> float:
    return max(dist, 0.0) / rate if rate > 1e-12 else math.inf


def kinematic_margin(
    pose: np.ndarray,
    pose_velocity: np.ndarray,
    q: np.ndarray,
    q_velocity: np.ndarray,
    features: np.ndarray,
    feature_rates: np.ndarray,
    hard: HardLimits,
    workspace: Mapping[str, tuple[float, float]] | None,
) -> KinematicMargin:
    """Margins from the pose (x, z, roll, pitch) [m, rad] and its rates, actuators and their rates,
    and the hard-limit feature rows with their rates (per second)."""
    candidates: list[tuple[float, str]] = []
    per_dof: dict[str, DofMargin] = {}
    for d, (k, (name_min, name_max)) in enumerate(zip(CONTROLLED_POSE_NAMES, WORKSPACE_NAMES, strict=True)):
        best = (math.inf, "")
        if workspace is not None:
            lo, hi = workspace[k]
            v = pose_velocity[d]
            best = min(best, (_time(hi - pose[d], v), name_max), (_time(pose[d] - lo, -v), name_min))
        per_dof[k] = {"time_s": best[0], "limit": best[1] if math.isfinite(best[0]) else ""}
        candidates.append(best)
    for i, (name_min, name_max) in enumerate(STROKE_NAMES):
        v = q_velocity[i]
        candidates.append((_time(hard.actuator_upper[i] - q[i], v), name_max))
        candidates.append((_time(q[i] - hard.actuator_lower[i], -v), name_min))
    f = features[list(hard.feature_index)]
    fr = feature_rates[list(hard.feature_index)]
    for j in range(len(f)):
        if hard.names_upper[j] and math.isfinite(hard.feature_upper[j]):
            candidates.append((_time(hard.feature_upper[j] - f[j], fr[j]), hard.names_upper[j]))
        candidates.append((_time(f[j] - hard.feature_lower[j], -fr[j]), hard.names_lower[j]))
    t, name = min(candidates)
    return KinematicMargin(t, name if math.isfinite(t) else "", per_dof)
