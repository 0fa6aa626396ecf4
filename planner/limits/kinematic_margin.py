"""Kinematic margin (seed 003): time to the nearest limit at the current velocity.

For each limit the time is distance-to-limit / rate-towards-it (∞ when moving away or at
rest). Reported per controlled DOF (the workspace faces) and overall (workspace faces,
actuator strokes, top-link angles, ground clearance), with the limit's name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from planner.model.hard_limits import HardLimits
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES

__all__ = ["KinematicMargin", "kinematic_margin"]


@dataclass(frozen=True)
class KinematicMargin:
    time_s: float  # overall, ∞ at rest
    limit: str  # the limit that would be reached first ("" at rest)
    per_dof: dict  # "x" → {"time_s", "limit"}

    def to_json(self) -> dict:
        def t(v):
            return None if math.isinf(v) else v

        return {
            "time_s": t(self.time_s),
            "limit": self.limit,
            "per_dof": {k: {"time_s": t(v["time_s"]), "limit": v["limit"]} for k, v in self.per_dof.items()},
        }


def _time(dist: float, rate: float) -> float:
    return max(dist, 0.0) / rate if rate > 1e-12 else math.inf


def kinematic_margin(
    pose, pose_velocity, q, q_velocity, features, feature_rates, hard: HardLimits, workspace: dict | None
) -> KinematicMargin:
    """Margins from the pose (x, z, roll, pitch) and its rates, actuators and their rates,
    and the hard-limit feature rows with their rates."""
    candidates: list[tuple[float, str]] = []
    per_dof = {}
    for d, k in enumerate(CONTROLLED_POSE_NAMES):
        best = (math.inf, "")
        if workspace is not None:
            lo, hi = workspace[k]
            v = pose_velocity[d]
            best = min(
                best, (_time(hi - pose[d], v), f"workspace:{k}:max"), (_time(pose[d] - lo, -v), f"workspace:{k}:min")
            )
        per_dof[k] = {"time_s": best[0], "limit": best[1] if math.isfinite(best[0]) else ""}
        candidates.append(best)
    for i, n in enumerate(ACTUATOR_NAMES):
        v = q_velocity[i]
        candidates.append((_time(hard.actuator_upper[i] - q[i], v), f"stroke:{n}:max"))
        candidates.append((_time(q[i] - hard.actuator_lower[i], -v), f"stroke:{n}:min"))
    f = features[list(hard.feature_index)]
    fr = feature_rates[list(hard.feature_index)]
    for k in range(len(f)):
        if hard.names_upper[k] and math.isfinite(hard.feature_upper[k]):
            candidates.append((_time(hard.feature_upper[k] - f[k], fr[k]), hard.names_upper[k]))
        candidates.append((_time(f[k] - hard.feature_lower[k], -fr[k]), hard.names_lower[k]))
    t, name = min(candidates)
    return KinematicMargin(t, name if math.isfinite(t) else "", per_dof)
