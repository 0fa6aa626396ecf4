"""Goto planning of the motion controller: guarded plans that start and replace motions.

:class:`GotoPlanningMixin` holds the :class:`~bridge.service.motion.controller.MotionController` methods
that plan (on the planning guard, outside the control lock) and install a
goto/preset/maneuver-step motion: :meth:`~GotoPlanningMixin.goto`,
:meth:`~GotoPlanningMixin.preview`, :meth:`~GotoPlanningMixin.plan_step` and the start of a
plan that replaces the running motion smoothly at a switch time ``_PLAN_LEAD_S`` ahead (if
planning takes longer, again from 1.5 × the time it took; a plan from rest starts whenever it
is ready, since a resting start does not age, unless it was the measured pose and the pistons
moved more than 5 mm / 5 mrad meanwhile). It uses the controller's state (locks, guards,
active motion, maneuver slot) and helpers, so it is only meant as a base of
:class:`~bridge.service.motion.controller.MotionController`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from bridge.service.maneuvers.runner import ManeuverRunner
from bridge.service.motion.types import MotionAccepted, MotionError, PlanMotion
from bridge.service.state_message import link_problem
from planner.model.types import CONTROLLED_POSE_NAMES
from planner.trajectory import MotionState

__all__ = ["GotoPlanningMixin"]

_PLAN_LEAD_S = 0.08  # a replacing plan starts this far ahead of the request (planning time)
_MOVED = 5e-3  # m or rad: a measured start pose that moved more while planning is re-planned


class GotoPlanningMixin:
    """Planning and starting goto/preset/maneuver-step motions (a base of ``MotionController``)."""

    # ------------------------------------------------------------------ commands
    def goto(
        self, goal: Mapping[str, float], speed_scale: float = 1.0, *, kind: str = "goto", label: str | None = None
    ) -> MotionAccepted:
        """Plan and start a move to a (partial) goal; replaces a running goto/preset/maneuver."""
        return self._start_plan(goal, speed_scale, kind, label, from_maneuver=False)

    def preview(self, goal: Mapping[str, float], speed_scale: float = 1.0):
        """The guarded plan a goto would run now (no motion); raises PlanError / GuardRefusal."""
        with self._lock:
            start = self._predict(self.clock() + _PLAN_LEAD_S, require_link=False)
        with self._plan_lock:
            return self.plan_guard.plan(start, goal, speed_scale=speed_scale)

    def plan_step(self, start: MotionState, goal: Mapping[str, float], speed_scale: float):
        """Guarded planning on the planning guard (for maneuver validation): (duration, end state)."""
        with self._plan_lock:
            gp = self.plan_guard.plan(start, goal, speed_scale=speed_scale)
        end = gp.plan.state_at(gp.plan.duration)
        return float(gp.plan.duration), MotionState.at_rest(end.position)

    # ------------------------------------------------------------------ internals: starting plans
    def _start_plan(
        self, goal, speed_scale, kind, label, *, from_maneuver: bool, runner: ManeuverRunner | None = None
    ) -> MotionAccepted:
        lead = _PLAN_LEAD_S
        for _ in range(4):
            with self._lock:
                now = self.clock()
                if not from_maneuver:
                    self._check_allowed(kind)
                    self._check_precedence()
                self._expire_jog(now)  # a dying jog is replaced from its braking plan
                why = link_problem(self.link.status(now), now, self.link.config.stale_after_s)
                if why:
                    raise MotionError("ecu", f"{kind} refused: {why}")
                t_switch = now + lead
                start = self._predict(t_switch)
                from_rest = self._active is None and not start.moving  # holding: the start does not age
                gen = self._generation
            t_plan = self.clock()
            with self._plan_lock:
                gp = self.plan_guard.plan(start, goal, speed_scale=speed_scale)  # PlanError / GuardRefusal
            took = self.clock() - t_plan
            events: list[dict] = []
            with self._lock:
                if from_maneuver and not self._maneuver.owns(runner):
                    raise MotionError("busy", "the maneuver was aborted while its step was being planned")
                if self._generation != gen:
                    if not from_maneuver:
                        self._check_precedence()
                    continue  # something else started meanwhile: re-plan from it
                now = self.clock()
                if from_rest and self._active is None:
                    if self._hold is None and np.max(np.abs(self._predict(now).position - start.position)) > _MOVED:
                        continue  # the measured start moved while planning (coasting): again
                    t_switch = max(t_switch, now)  # from rest the plan may start whenever it is ready
                elif now > t_switch - 0.25 * self.dt:
                    lead = max(2 * lead, 1.5 * took + self.dt)  # planning took longer: again, further ahead
                    continue
                prev = self._active if isinstance(self._active, PlanMotion) else None
                if self._active is not None:
                    events.append(self._ev("motion_aborted", self._active, reason=f"replaced by {kind}"))
                if not from_maneuver:
                    self._maneuver.abort(now, "interrupted", f"replaced by {kind}", events)
                pm = PlanMotion(kind, next(self._ids), gp.plan, t_switch, prev, gp.decision, label)
                self._install(pm)
                events.append(
                    self._ev(
                        "motion_started",
                        pm,
                        kind=kind,
                        duration=gp.plan.duration,
                        goal=dict(zip(CONTROLLED_POSE_NAMES, map(float, gp.plan.state_at(gp.plan.duration).position))),
                        label=label,
                    )
                )
                if runner is not None:
                    runner.motion_started(pm.motion_id)
                acc = MotionAccepted(pm.motion_id, gp.plan.duration, kind, gp.decision)
            self._emit_all(events)
            return acc
        raise MotionError("busy", f"{kind} could not be started: the service is too busy to plan in time")
