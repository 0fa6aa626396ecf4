"""Maneuvers: YAML scripts of hitch steps, validated by planning and run by the control loop.

* :mod:`bridge.service.maneuvers.steps` — the step schema (one strict model per step kind) and
  its bounds;
* :mod:`bridge.service.maneuvers.language` — parsing (:func:`parse_maneuver`, errors per step)
  and validation by planning every motion step (:func:`validate`);
* :mod:`bridge.service.maneuvers.runner` — :class:`ManeuverRunner`: the pure step logic of one
  run, one control tick at a time;
* :mod:`bridge.service.maneuvers.slot` — :class:`ManeuverSlot`: the motion controller's running
  maneuver.

The names below load lazily (PEP 562): ``import bridge.service.maneuvers`` imports none of the modules.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from bridge.service.maneuvers.language import (
        MAX_SCRIPT_BYTES,
        MAX_STEPS,
        ManeuverError,
        PlannedStep,
        PlanningContext,
        PlanStep,
        PresetLike,
        StepError,
        ValidationResult,
        guarded_plan_step,
        parse_maneuver,
        validate,
    )
    from bridge.service.maneuvers.recorder import ManeuverRecorder, RecorderError
    from bridge.service.maneuvers.runner import (
        AbortReason,
        Command,
        LoopState,
        ManeuverRunError,
        ManeuverRunner,
        RunnerStatus,
    )
    from bridge.service.maneuvers.slot import ManeuverProgress, ManeuverSlot
    from bridge.service.maneuvers.steps import (
        DEFAULT_TIMEOUT_S,
        MAX_TIMEOUT_S,
        MIN_SPEED_SCALE,
        NAME_PATTERN,
        POSE_BOUNDS,
        GotoStep,
        ManeuverSchemaError,
        ManeuverScript,
        PresetStep,
        SpeedStep,
        Step,
        WaitForStep,
        WaitStep,
        check_name,
        step_words,
    )

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(
        (
            "ManeuverSchemaError",
            "DEFAULT_TIMEOUT_S",
            "MAX_TIMEOUT_S",
            "MIN_SPEED_SCALE",
            "POSE_BOUNDS",
            "NAME_PATTERN",
            "GotoStep",
            "PresetStep",
            "WaitStep",
            "WaitForStep",
            "SpeedStep",
            "Step",
            "ManeuverScript",
            "check_name",
            "step_words",
        ),
        "bridge.service.maneuvers.steps",
    ),
    **dict.fromkeys(
        (
            "MAX_SCRIPT_BYTES",
            "MAX_STEPS",
            "ManeuverError",
            "StepError",
            "PlannedStep",
            "ValidationResult",
            "PlanningContext",
            "PlanStep",
            "PresetLike",
            "parse_maneuver",
            "validate",
            "guarded_plan_step",
        ),
        "bridge.service.maneuvers.language",
    ),
    **dict.fromkeys(
        ("Command", "LoopState", "ManeuverRunner", "ManeuverRunError", "AbortReason", "RunnerStatus"),
        "bridge.service.maneuvers.runner",
    ),
    **dict.fromkeys(("ManeuverSlot", "ManeuverProgress"), "bridge.service.maneuvers.slot"),
    **dict.fromkeys(("ManeuverRecorder", "RecorderError"), "bridge.service.maneuvers.recorder"),
}

__all__ = [
    # the step schema (bridge.service.maneuvers.steps)
    "ManeuverSchemaError",
    "DEFAULT_TIMEOUT_S",
    "MAX_TIMEOUT_S",
    "MIN_SPEED_SCALE",
    "POSE_BOUNDS",
    "NAME_PATTERN",
    "GotoStep",
    "PresetStep",
    "WaitStep",
    "WaitForStep",
    "SpeedStep",
    "Step",
    "ManeuverScript",
    "check_name",
    "step_words",
    # parsing and validation (bridge.service.maneuvers.language)
    "MAX_SCRIPT_BYTES",
    "MAX_STEPS",
    "ManeuverError",
    "StepError",
    "PlannedStep",
    "ValidationResult",
    "PlanningContext",
    "PlanStep",
    "PresetLike",
    "parse_maneuver",
    "validate",
    "guarded_plan_step",
    # running one maneuver (bridge.service.maneuvers.runner)
    "Command",
    "LoopState",
    "ManeuverRunner",
    "ManeuverRunError",
    "AbortReason",
    "RunnerStatus",
    # the controller's running maneuver (bridge.service.maneuvers.slot)
    "ManeuverSlot",
    "ManeuverProgress",
    # teach-in (bridge.service.maneuvers.recorder)
    "ManeuverRecorder",
    "RecorderError",
]


if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(__name__, globals(), _SOURCES)
