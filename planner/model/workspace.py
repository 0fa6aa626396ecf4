"""Reachability of poses and the restricted (operator-level) workspace box.

A pose (x, z, roll, pitch) is *reachable* when the exact inverse
(:class:`~planner.model.exact_inverse.ExactInverse`) finds actuators for it and those
actuators respect every hard limit (:class:`~planner.model.hard_limits.HardLimits`).

The restricted workspace is an axis-aligned box that lies wholly inside the reachable
set (the free-gait source's "restricted workspace", docs/source_thesis.md §9).
:func:`fit_restricted_box` grows it from the
neutral pose, face by face in equal relative steps of the thesis's table 3-7 ranges,
as long as every grid point of the grown face is reachable and the face stays within
the table 3-7 box. The result is maximal: no face can move outwards by one more step.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from planner.model.exact_inverse import ExactInverse
from planner.model.hard_limits import HardLimits
from planner.model.kinematics import HitchModel
from planner.model.types import CONTROLLED_POSE_NAMES, KinematicsError

__all__ = ["Reachability", "fit_restricted_box", "box_grid", "FitResult"]


class Reachability:
    """Answers "is this pose reachable within the hard limits?" for one model."""

    def __init__(self, model: HitchModel, limits: HardLimits | None = None):
        self.model = model
        self.inverse = ExactInverse(model)
        self.limits = limits or HardLimits.from_model(model)

    def check(self, target) -> tuple[bool, tuple[str, ...]]:
        """(reachable, names of the violated limits or the kinematic cause)."""
        try:
            q = self.inverse(*target)
            f, _ = self.model.features(q)
        except KinematicsError as exc:
            return False, (f"kinematics: {exc}",)
        v = self.limits.violations(q, f)
        return (not v), v

    def __call__(self, target) -> bool:
        return self.check(target)[0]


def box_grid(box: dict[str, tuple[float, float]], n: int = 5) -> np.ndarray:
    """All points of an n^4 grid over the box (rows x, z, roll, pitch)."""
    axes = [np.linspace(box[k][0], box[k][1], n) for k in CONTROLLED_POSE_NAMES]
    return np.array(list(itertools.product(*axes)))


@dataclass(frozen=True)
class FitResult:
    box: dict[str, tuple[float, float]]
    #: for each face "<dof>:min|max": what stopped it ("thesis box" or a limit name)
    stopped_by: dict[str, str]


def fit_restricted_box(
    model: HitchModel,
    *,
    step_fraction: float = 0.01,
    face_points: int = 5,
    reach: Reachability | None = None,
) -> FitResult:
    """Grow the largest box around the neutral pose inside the reachable set and the thesis box.

    ``step_fraction`` is the growth step as a fraction of each thesis-box range (1 % =
    6.6 mm in z, 2 mm in x, 2 mrad in roll and pitch); ``face_points`` the grid
    resolution used on each face.
    """
    reach = reach or Reachability(model)
    outer = model.thesis_box()
    p0 = model.neutral_pose.controlled()
    ok, why = reach.check(p0)
    if not ok:
        raise KinematicsError(
            f"category {model.category}: the neutral pose is outside the hard limits ({', '.join(why)}); "
            "no restricted workspace exists around it"
        )
    lo = {k: float(p0[i]) for i, k in enumerate(CONTROLLED_POSE_NAMES)}
    hi = dict(lo)
    steps = {k: step_fraction * (outer[k][1] - outer[k][0]) for k in CONTROLLED_POSE_NAMES}
    open_faces = [(k, side) for k in CONTROLLED_POSE_NAMES for side in ("min", "max")]
    stopped: dict[str, str] = {}
    while open_faces:
        for face in list(open_faces):
            k, side = face
            new = lo[k] - steps[k] if side == "min" else hi[k] + steps[k]
            limit = outer[k][0] if side == "min" else outer[k][1]
            if (side == "min" and new < limit) or (side == "max" and new > limit):
                stopped[f"{k}:{side}"] = "thesis box"
                if reach_face(reach, lo, hi, k, limit, face_points) is True:
                    if side == "min":
                        lo[k] = limit
                    else:
                        hi[k] = limit
                open_faces.remove(face)
                continue
            blocked = reach_face(reach, lo, hi, k, new, face_points, report=True)
            if blocked is True:
                if side == "min":
                    lo[k] = new
                else:
                    hi[k] = new
            else:
                stopped[f"{k}:{side}"] = blocked
                open_faces.remove(face)
    box = {k: (lo[k], hi[k]) for k in CONTROLLED_POSE_NAMES}
    return FitResult(box=box, stopped_by=stopped)


def reach_face(reach: Reachability, lo, hi, key: str, value: float, n: int, report: bool = False):
    """True when every grid point of the face ``key = value`` of the box is reachable;
    otherwise False (or, with ``report``, the name of the first violated limit)."""
    axes = []
    for k in CONTROLLED_POSE_NAMES:
        axes.append([value] if k == key else np.linspace(lo[k], hi[k], n if hi[k] > lo[k] else 1))
    for t in itertools.product(*axes):
        ok, why = reach.check(np.array(t))
        if not ok:
            return why[0] if report else False
    return True
