"""The end of a goto streamed as whole counts: the profile's count approach with its references in SI.

:mod:`planner.trajectory.count_approach` chooses, per actuator, the count, the side and the back-off from
which the ECU's stop inside that count is nearest the goal. Here that choice becomes what the link streams
after the plan: the via references for ``via_hold_s``, then the final ones, each at its count's centre (the
link rounds it back to that count), both checked by the link first. The service's control cycle
(``bridge/service/motion``) and the twin's goto runner (``bridge/sim/accuracy_run.py``) stream the same.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from planner.model.sensors import SensorScaling
from planner.profiles.hitch import Profile
from planner.trajectory.count_approach import CountApproach, count_approach_for
from planner.trajectory.plan import Plan

__all__ = ["CountTail", "arrival_sides", "build_count_tail", "plan_count_tail"]

#: an actuator the final approach moves less than this arrives from no side (either is allowed) [counts]
_STILL_COUNTS = 1e-6


@dataclass(frozen=True)
class CountTail:
    """A goto's count approach with its references in SI (lift [rad], the others [m]): ``via_actuators``
    first, then ``final_actuators``."""

    approach: CountApproach
    via_actuators: np.ndarray
    final_actuators: np.ndarray

    def actuators_at(self, t_after_plan_s: float) -> np.ndarray:
        """The reference ``t_after_plan_s`` seconds after the plan's end (SI)."""
        return self.via_actuators if t_after_plan_s < self.approach.via_hold_s else self.final_actuators


def arrival_sides(
    goal: ArrayLike, rise: ArrayLike, solve: Callable[[np.ndarray], np.ndarray], scaling: SensorScaling
) -> np.ndarray:
    """Per actuator the side a final approach (``motion.final_approach``: the goto rises by ``rise`` [m, m,
    rad, rad] into ``goal``) brings it from: +1 rising in counts, −1 falling, the sign of its change from
    ``goal − rise`` to ``goal`` (0 where it does not change). ``solve``: pose (4) → actuators (SI)."""
    p1 = np.asarray(goal, float)
    q1 = np.asarray(solve(p1), float)
    q0 = np.asarray(solve(p1 - np.asarray(rise, float)), float)
    dc = (q1 - q0) / scaling.resolution
    return np.where(np.abs(dc) < _STILL_COUNTS, 0.0, np.sign(dc))


def build_count_tail(
    profile: Profile,
    goal_actuators: ArrayLike,
    check_reference: Callable[[np.ndarray], object],
    sides: ArrayLike | None = None,
) -> CountTail | None:
    """The count approach of ``profile`` (``motion.count_approach``) to the goal's actuators
    ``goal_actuators`` (SI), with its via and final references passed through ``check_reference`` (the
    link's: it raises ``ReferenceRefused``, a ``ValueError``, outside a hard limit); ``sides`` (per actuator
    +1, −1, 0: :func:`arrival_sides`) is kept when the setting ``keep_arrival_side`` says so. None without the
    setting, or when one of them would be refused (a goal next to a hard limit ends as its plan does)."""
    settings = profile.motion.count_approach
    if settings is None:
        return None
    sc = SensorScaling(profile)
    try:
        approach = count_approach_for(
            settings, sc, goal_actuators, sc.counts_min, sc.counts_max, sides if settings.keep_arrival_side else None
        )
        via, final = sc.to_si(approach.via_counts), sc.to_si(approach.final_counts)
        check_reference(via)
        check_reference(final)
    except ValueError:  # CountApproachError, ReferenceRefused: no approach at this goal
        return None
    return CountTail(approach, via, final)


def plan_count_tail(
    profile: Profile,
    plan: Plan,
    solve: Callable[[np.ndarray], np.ndarray],
    check_reference: Callable[[np.ndarray], object],
) -> CountTail | None:
    """:func:`build_count_tail` at ``plan``'s goal, each actuator from the side of the profile's final approach
    (:func:`arrival_sides`; without one, either side). ``solve``: pose → actuators (SI); a pose it cannot solve
    raises its ``KinematicsError``, a ``ValueError``: no tail then."""
    if profile.motion.count_approach is None:
        return None
    fa = profile.motion.final_approach
    try:
        goal = np.asarray(plan.state_at(plan.duration).position, float)
        q = np.asarray(solve(goal), float)
        sides = None if fa is None else arrival_sides(goal, fa.offset(), solve, SensorScaling(profile))
    except ValueError:
        return None
    return build_count_tail(profile, q, check_reference, sides)
