"""The hard (free-workspace) limits of the hitch, evaluated on actuators and features.

Hard limits are what the machine cannot or must not exceed: actuator strokes (thesis
table 3-1/3-2), top-link angles relative to its tractor mount (thesis §3.2, §2.2.8: 0.15 rad
each way horizontally, 0.35 rad upwards) and the lower-link ends' ground clearance.
Names follow one scheme everywhere (IK ``active`` lists, refusals, "Control limited"),
:class:`~planner.model.limit_names.LimitName`: ``stroke:<actuator>:min|max``,
``top_link_yaw_min|max``, ``top_link_pitch_min|max``, ``ground_clearance_left|right``,
``workspace:<dof>:min|max``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.model.kinematics import FEATURE_NAMES, HitchModel
from planner.model.limit_names import LimitName
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES

__all__ = ["HardLimits", "FEATURE_LIMIT_ROWS", "LimitName", "STROKE_NAMES", "WORKSPACE_NAMES"]

#: Feature rows that carry hard limits, with the names used for their min/max sides ("" = none).
FEATURE_LIMIT_ROWS: tuple[tuple[str, str, str], ...] = (
    (
        "top_link_yaw",
        str(LimitName("top_link_yaw", side="min", flat=True)),
        str(LimitName("top_link_yaw", side="max", flat=True)),
    ),
    (
        "top_link_pitch",
        str(LimitName("top_link_pitch", side="min", flat=True)),
        str(LimitName("top_link_pitch", side="max", flat=True)),
    ),
    ("z_left_end", str(LimitName("ground_clearance", "left", flat=True)), ""),
    ("z_right_end", str(LimitName("ground_clearance", "right", flat=True)), ""),
)
#: ``(stroke:<actuator>:min, stroke:<actuator>:max)`` per actuator, order ACTUATOR_NAMES.
STROKE_NAMES: tuple[tuple[str, str], ...] = tuple(
    (str(LimitName("stroke", n, "min")), str(LimitName("stroke", n, "max"))) for n in ACTUATOR_NAMES
)
#: ``(workspace:<dof>:min, workspace:<dof>:max)`` per controlled DOF, order CONTROLLED_POSE_NAMES:
#: the faces of the restricted workspace (a soft limit the motion layers add to the hard ones).
WORKSPACE_NAMES: tuple[tuple[str, str], ...] = tuple(
    (str(LimitName("workspace", k, "min")), str(LimitName("workspace", k, "max"))) for k in CONTROLLED_POSE_NAMES
)


@dataclass(frozen=True)
class HardLimits:
    """Hard limits of one model. Arrays in SI; feature bounds act on the raw feature rows."""

    actuator_lower: np.ndarray
    actuator_upper: np.ndarray
    feature_index: tuple[int, ...]  # rows of FEATURE_NAMES with bounds
    feature_lower: np.ndarray
    feature_upper: np.ndarray
    names_lower: tuple[str, ...]
    names_upper: tuple[str, ...]

    @classmethod
    def from_model(cls, model: HitchModel) -> HardLimits:
        lim = model.profile.limits
        yaw0, pitch0 = model.top_link_reference
        ground = -model.profile.geometry.pivot_height + lim.ground_clearance
        lower = np.array([yaw0 - lim.top_link_yaw_max, pitch0 - lim.top_link_pitch_down_max, ground, ground])
        upper = np.array([yaw0 + lim.top_link_yaw_max, pitch0 + lim.top_link_pitch_up_max, np.inf, np.inf])
        return cls(
            actuator_lower=model.lower.copy(),
            actuator_upper=model.upper.copy(),
            feature_index=tuple(FEATURE_NAMES.index(r[0]) for r in FEATURE_LIMIT_ROWS),
            feature_lower=lower,
            feature_upper=upper,
            names_lower=tuple(r[1] for r in FEATURE_LIMIT_ROWS),
            names_upper=tuple(r[2] for r in FEATURE_LIMIT_ROWS),
        )

    def violations(self, q: np.ndarray, features: np.ndarray, tol: float = 1e-9) -> tuple[str, ...]:
        """Names of the hard limits that ``q`` (actuators) and its ``features`` exceed by more than ``tol``.
        A NaN lies within no limit: it is reported as below its lower one (it passed every check before)."""
        out = []
        for i, (name_min, name_max) in enumerate(STROKE_NAMES):
            if not q[i] >= self.actuator_lower[i] - tol:
                out.append(name_min)
            elif q[i] > self.actuator_upper[i] + tol:
                out.append(name_max)
        f = features[list(self.feature_index)]
        for k in range(len(f)):
            if not f[k] >= self.feature_lower[k] - tol:
                out.append(self.names_lower[k])
            elif f[k] > self.feature_upper[k] + tol:
                out.append(self.names_upper[k])
        return tuple(out)
