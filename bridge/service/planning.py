"""Where the expensive requests run: plan previews, maneuver validation and IK.

:class:`Planning` is the seam :class:`~bridge.service.api.ServiceAPI` uses for them. Two
implementations:

* :class:`~bridge.service.workers.PlanningWorkers` — worker processes (what ``hitch serve``
  runs): nothing of this work holds the service process's interpreter lock;
* :class:`InProcessPlanning` — on the calling thread, on the motion controller's planning
  guard (under its lock) and an IK solver of its own (under a lock): for a service embedded in
  a test or a script, and the reference the workers are tested against. With the control core
  in a process of its own and no planning processes, the service's process plans on a guard of
  its own (:class:`GuardPlanning`), never in the core.

Both answer the same values: the ``plan`` reply, a
:class:`~bridge.service.maneuvers.language.ValidationResult`, the IK solution's JSON; and
raise the same :class:`~bridge.service.workers.WorkerError` codes for ``ik_failed``.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import Any, Protocol

from bridge.service.maneuvers.language import ManeuverScript, PlanningContext, PlanStep, PresetLike, ValidationResult
from bridge.service.maneuvers.language import validate as validate_script
from bridge.service.motion.types import PlanPreview
from bridge.service.workers import WorkerError
from planner.trajectory import MotionState, PlanError

__all__ = ["GuardPlanning", "InProcessPlanning", "MotionPlanning", "Planning"]


class Planning(Protocol):
    """The expensive requests, given the start state the controller predicts."""

    def preview(self, start: MotionState, goal: Mapping[str, float], speed_scale: float) -> dict[str, Any]:
        """The ``plan`` reply (a plan or its refusal)."""
        ...

    def validate(
        self, script: ManeuverScript, start: MotionState, presets: Mapping[str, PresetLike]
    ) -> ValidationResult:
        """The validation of a parsed script from ``start`` with the presets it names."""
        ...

    def ik(self, target: tuple[float, float, float, float]) -> dict[str, Any]:
        """The IK solution's JSON (``ik_failed`` :class:`WorkerError` when there is none)."""
        ...


class MotionPlanning(Protocol):
    """What :class:`InProcessPlanning` needs of the motion controller."""

    def preview_from(self, start: MotionState, goal: Mapping[str, float], speed_scale: float) -> Any:
        """The guarded plan from ``start`` (PlanError / GuardRefusal when refused)."""
        ...

    def preview_with_tail(self, start: MotionState, goal: Mapping[str, float], speed_scale: float) -> tuple[Any, Any]:
        """The guarded plan from ``start`` and the count approach a goto of it would end with
        (:mod:`bridge.link.count_tail`; None: none), on one guard state (PlanError / GuardRefusal when refused)."""
        ...

    def plan_step(
        self, start: MotionState, goal: Mapping[str, float], speed_scale: float
    ) -> tuple[float, MotionState]: ...


class GuardPlanning:
    """:class:`MotionPlanning` on a guard of its own (under a lock), in the process that calls it.

    For a service whose control core runs in another process and that has no planning processes:
    the core's guards are not here, and planning must not load the core. ``set_implement`` gives
    the guard the selected implement, as the planning processes get it.
    """

    def __init__(self, guard: Any):
        from bridge.link.reference_check import ReferenceCheck
        from bridge.service.maneuvers.language import guarded_plan_step

        self._guard = guard
        self._lock = threading.Lock()
        self._plan_step = guarded_plan_step(guard)
        self._check = ReferenceCheck(guard.planner.model)  # the link's check, on this guard's model

    def preview_from(self, start: MotionState, goal: Mapping[str, float], speed_scale: float) -> Any:
        with self._lock:
            return self._guard.plan(start, goal, speed_scale=speed_scale)

    def preview_with_tail(self, start: MotionState, goal: Mapping[str, float], speed_scale: float) -> tuple[Any, Any]:
        from bridge.link.count_tail import plan_count_tail

        with self._lock:
            gp = self._guard.plan(start, goal, speed_scale=speed_scale)
            return gp, plan_count_tail(self._guard.planner, gp.plan, self._check, self._guard)

    def plan_step(self, start: MotionState, goal: Mapping[str, float], speed_scale: float) -> tuple[float, MotionState]:
        with self._lock:
            return self._plan_step(start, goal, speed_scale)

    def set_implement(self, implement: Any, limits: Any) -> None:
        """The selected implement's record and limits for every later plan (``implements/select``)."""
        with self._lock:
            self._guard.set_implement(implement)
            self._guard.set_implement_limits(limits)


class InProcessPlanning:
    """:class:`Planning` on the calling thread (module docstring).

    Args:
        motion: the controller (its planning guard, under its planning lock).
        ik: an IK solver used by this object only (under a lock), or None (``ik`` unavailable).
    """

    def __init__(self, motion: MotionPlanning, ik: Any):
        self._motion, self._ik = motion, ik
        self._ik_lock = threading.Lock()

    def preview(self, start: MotionState, goal: Mapping[str, float], speed_scale: float) -> dict[str, Any]:
        try:
            return PlanPreview.planned(*self._motion.preview_with_tail(start, goal, speed_scale)).to_json()
        except PlanError as exc:  # the planner's or the guard's (GuardRefusal) refusal
            return PlanPreview.refusal(exc).to_json()

    def validate(
        self, script: ManeuverScript, start: MotionState, presets: Mapping[str, PresetLike]
    ) -> ValidationResult:
        step: PlanStep = self._motion.plan_step
        return validate_script(script, PlanningContext(start, step, presets.get))

    def set_implement(self, implement: Any, limits: Any) -> None:
        """Pass the selected implement on when the planning is a :class:`GuardPlanning` (a controller's
        own guards follow its ``select_implement``)."""
        forward = getattr(self._motion, "set_implement", None)
        if callable(forward):
            forward(implement, limits)

    def ik(self, target: tuple[float, float, float, float]) -> dict[str, Any]:
        from planner.ik_qp.result import Target

        if self._ik is None:
            raise WorkerError("unavailable", "no IK solver in this service")
        with self._ik_lock:
            res = self._ik.solve(Target(*target))
        if res.status == "failed":
            raise WorkerError("ik_failed", f"no solution ({res.reason})")
        return dict(res.to_json())
