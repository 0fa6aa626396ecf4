"""The end of a goto streamed as whole counts: the profile's count approach with its references in SI.

:mod:`planner.trajectory.count_approach` chooses, per actuator, the count, the side and the back-off from
which the ECU's stop inside that count is nearest the goal. Here that choice becomes what the link streams
after the plan: the via references for ``via_hold_s``, then the final ones, each at its count's centre (the
link rounds it back to that count), both checked by the link first. The service's control cycle
(``bridge/service/motion``) and the twin's goto runner (``bridge/sim/accuracy_run.py``) stream the same.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from planner.limits.guard import Guard
from planner.model.sensors import SensorScaling
from planner.profiles.hitch import Profile
from planner.trajectory.count_approach import CountApproach, count_approach_for
from planner.trajectory.plan import Plan, Setpoints
from planner.trajectory.planner import TrajectoryPlanner

__all__ = ["CountTail", "arrival_sides", "build_count_tail", "plan_count_tail"]

#: an actuator the final approach moves less than this arrives from no side (either is allowed) [counts]
_STILL_COUNTS = 1e-6
#: how far a via pose may lie outside the workspace box [m, rad] (rounding of its counts' centres aside)
_BOX_TOL = 1e-9


@dataclass(frozen=True)
class CountTail:
    """A goto's count approach with its references in SI (lift [rad], the others [m]): ``via_actuators``
    first, then ``final_actuators``; ``via_pose`` and ``final_pose``: the poses (x, z, roll, pitch [m, rad])
    of those references through the planner's model (:func:`plan_count_tail`; None from
    :func:`build_count_tail`, which has no model)."""

    approach: CountApproach
    via_actuators: np.ndarray
    final_actuators: np.ndarray
    via_pose: np.ndarray | None = None
    final_pose: np.ndarray | None = None

    def actuators_at(self, t_after_plan_s: float) -> np.ndarray:
        """The reference ``t_after_plan_s`` seconds after the plan's end (SI)."""
        return self.via_actuators if t_after_plan_s < self.approach.via_hold_s else self.final_actuators

    def pose_at(self, t_after_plan_s: float) -> np.ndarray | None:
        """The pose of :meth:`actuators_at` (None when not known): where a motion after it starts."""
        return self.via_pose if t_after_plan_s < self.approach.via_hold_s else self.final_pose


def arrival_sides(jacobian: ArrayLike, rise: ArrayLike, scaling: SensorScaling) -> np.ndarray:
    """Per actuator the side of its count step (via → final count) that moves the implement the way the final
    approach does: the sign, in counts, of ``jacobian`` (dq/dpose at the goal, 5 × 4) times ``rise``
    (``motion.final_approach``'s :meth:`~planner.profiles.hitch.FinalApproach.rise`, negative ending from above,
    [m, m, rad, rad]): +1 rising in counts, −1 falling, 0 where it does not change.
    The count step is the goto's last motion, so it decides on which side the pin play ends (the direction the
    plan arrived from does not: following that let the play swing, pitch p95 2.5–3.7 mrad against 1.2–1.7 on the
    twin)."""
    dc = (np.asarray(jacobian, float) @ np.asarray(rise, float)) / scaling.resolution
    return np.where(np.abs(dc) < _STILL_COUNTS, 0.0, np.sign(dc))


def build_count_tail(
    profile: Profile,
    goal_actuators: ArrayLike,
    check_reference: Callable[[np.ndarray], object],
    sides: ArrayLike | None = None,
    *,
    nearest_only: bool = False,
) -> CountTail | None:
    """The count approach of ``profile`` (``motion.count_approach``) to the goal's actuators
    ``goal_actuators`` (SI), with its via and final references passed through ``check_reference`` (the
    link's: it raises ``ReferenceRefused``, a ``ValueError``, outside a hard limit); ``sides`` (per actuator
    +1, −1, 0: :func:`arrival_sides`) is kept when the setting ``keep_arrival_side`` says so. None without the
    setting, or when one of them would be refused (a goal next to a hard limit ends as its plan does).
    ``nearest_only``: back-offs of one count only (the via next to the final count)."""
    settings = profile.motion.count_approach
    if settings is None:
        return None
    if nearest_only:
        settings = settings.model_copy(
            update={
                "from_below_counts": settings.from_below_counts.first_only(),
                "from_above_counts": settings.from_above_counts.first_only(),
            }
        )
    sc = SensorScaling(profile)
    try:
        approach = count_approach_for(settings, sc, goal_actuators, sides if settings.keep_arrival_side else None)
        via, final = sc.to_si(approach.via_counts), sc.to_si(approach.final_counts)
        check_reference(via)
        check_reference(final)
    except ValueError:  # CountApproachError, ReferenceRefused: no approach at this goal
        return None
    return CountTail(approach, via, final)


def plan_count_tail(
    planner: TrajectoryPlanner,
    plan: Plan,
    check_reference: Callable[[np.ndarray], object],
    guard: Guard | None = None,
) -> CountTail | None:
    """:func:`build_count_tail` at ``plan``'s goal for ``planner``'s profile, each actuator from the side whose
    count step moves the implement as the profile's final approach does (:func:`arrival_sides`; without a final
    approach: either side). The via and final poses must lie inside the planner's workspace box and pass
    ``guard`` as the rest of a move from the goal (its hard, implement, keep-out and stability limits: not
    refused); where the chosen via fails, back-offs of one count only, and where that fails too, no tail (the
    goto ends as its plan does). A pose the inverse cannot solve: no tail. ``planner`` and ``guard``: the
    caller's own (models are not thread-safe)."""
    profile = planner.model.profile
    if profile.motion.count_approach is None:
        return None

    try:
        goal = np.asarray(plan.state_at(plan.duration).position, float)
        q, jac = (np.asarray(v, float) for v in planner.inverse.solve(goal)[:2])
        fa = profile.motion.final_approach
        sides = None if fa is None else arrival_sides(jac, fa.rise(), SensorScaling(profile))
        for nearest_only in (False, True):
            tail = build_count_tail(profile, q, check_reference, sides, nearest_only=nearest_only)
            if tail is None:
                return None
            poses = _admissible(planner, guard, tail, q)
            if poses is not None:
                return replace(tail, via_pose=poses[0], final_pose=poses[1])
    except ValueError:  # KinematicsError: a goal or via the mechanism cannot take
        return None
    return None


def _admissible(
    planner: TrajectoryPlanner, guard: Guard | None, tail: CountTail, goal_q: np.ndarray
) -> np.ndarray | None:
    """The via and final poses (2 × 4: x, z, roll, pitch) if both lie inside the workspace box and (with a
    guard) are not refused by it as the rest of a move from the goal (``goal_q``, where the plan leaves the
    hitch: a move's start is its reference, e.g. for the implement's upper height); None otherwise."""
    q = np.vstack([goal_q, tail.via_actuators, tail.final_actuators])
    poses = np.array([planner.model.forward(qk).pose.as_array() for qk in q])
    ctrl = poses[1:, [0, 2, 3, 4]]
    if np.any(ctrl < planner.lo - _BOX_TOL) or np.any(ctrl > planner.hi + _BOX_TOL):
        return None
    if guard is not None:
        hold = tail.approach.via_hold_s
        t = np.array([0.0, hold, 2.0 * hold])
        sp = Setpoints(planner.rate, t, poses, np.zeros((3, 4)), q, np.zeros((3, 5)))
        if guard.check_setpoints(sp, rest_poses=True).action == "refused":  # poses at rest: no speed between
            return None
    return ctrl
