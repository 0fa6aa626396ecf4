"""The motion controller of the service: one motion at a time, streamed to the ECU over CAN.

* :mod:`bridge.service.motion.controller` — :class:`MotionController`: the control thread,
  goto/preset/maneuver-step planning and the smooth hand-over, jog, stop, modes, faults;
* :mod:`bridge.service.motion.fault_book` — :class:`FaultBook`: the faults the controller holds and the
  policy that raises, clears and acknowledges them (``docs/faults.md``);
* :mod:`bridge.service.motion.link_port` — :class:`LinkPort`, what the controller needs of the
  CAN link (:class:`bridge.link.can_link.CanLink` satisfies it);
* :mod:`bridge.service.motion.outbox` — :class:`Outbox`: events numbered (``seq``) and delivered
  in order, state messages serialised, off the control thread;
* :mod:`bridge.service.motion.types` — its values: modes, refusals (:class:`MotionError`), the
  accepted-motion replies, the plan preview, the active-motion records, the streamed reference,
  the fault records and policy constants (``docs/faults.md``).

The names below load lazily (PEP 562): ``import bridge.service.motion`` imports none of the modules.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from bridge.service.motion.controller import MotionController, MotionControllerError
    from bridge.service.motion.fault_book import FaultBook
    from bridge.service.motion.link_port import LinkPort
    from bridge.service.motion.outbox import Outbox
    from bridge.service.motion.types import (
        ATTACH_SPEED_SCALE,
        DEFAULT_DEADLINE_S,
        FAULT_CLEAR_AFTER_S,
        MODES,
        MOTION_MODES,
        SELF_CLEARING_FAULTS,
        ActiveMotion,
        Event,
        Fault,
        FaultAck,
        JogAccepted,
        JogMotion,
        ManeuverAccepted,
        MotionAccepted,
        MotionError,
        PlanMotion,
        PlanPreview,
        Reference,
        StabilityMargins,
        TailNow,
        actuator_dict,
        check_mode_allows,
        check_precedence,
        guard_limits,
        plan_state,
        pose_dict,
        running_at,
        streamed_reference,
        tail_at,
    )

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(("MotionController", "MotionControllerError"), "bridge.service.motion.controller"),
    **dict.fromkeys(("FaultBook",), "bridge.service.motion.fault_book"),
    **dict.fromkeys(("LinkPort",), "bridge.service.motion.link_port"),
    **dict.fromkeys(("Outbox",), "bridge.service.motion.outbox"),
    **dict.fromkeys(
        (
            "DEFAULT_DEADLINE_S",
            "FAULT_CLEAR_AFTER_S",
            "SELF_CLEARING_FAULTS",
            "Fault",
            "FaultAck",
            "MODES",
            "MOTION_MODES",
            "ATTACH_SPEED_SCALE",
            "Event",
            "MotionError",
            "MotionAccepted",
            "JogAccepted",
            "ManeuverAccepted",
            "PlanPreview",
            "StabilityMargins",
            "PlanMotion",
            "JogMotion",
            "ActiveMotion",
            "Reference",
            "actuator_dict",
            "check_mode_allows",
            "check_precedence",
            "guard_limits",
            "plan_state",
            "pose_dict",
            "running_at",
            "streamed_reference",
            "tail_at",
            "TailNow",
        ),
        "bridge.service.motion.types",
    ),
}

__all__ = [
    # the controller (bridge.service.motion.controller)
    "MotionController",
    "MotionControllerError",
    # its faults and their policy (bridge.service.motion.fault_book)
    "FaultBook",
    # its seam to the CAN link (bridge.service.motion.link_port)
    "LinkPort",
    # its outbox (bridge.service.motion.outbox)
    "Outbox",
    # its values (bridge.service.motion.types)
    "DEFAULT_DEADLINE_S",
    "FAULT_CLEAR_AFTER_S",
    "SELF_CLEARING_FAULTS",
    "Fault",
    "FaultAck",
    "MODES",
    "MOTION_MODES",
    "ATTACH_SPEED_SCALE",
    "Event",
    "MotionError",
    "MotionAccepted",
    "JogAccepted",
    "ManeuverAccepted",
    "PlanPreview",
    "StabilityMargins",
    "PlanMotion",
    "JogMotion",
    "ActiveMotion",
    "Reference",
    "actuator_dict",
    "check_mode_allows",
    "check_precedence",
    "guard_limits",
    "plan_state",
    "pose_dict",
    "running_at",
    "streamed_reference",
    "tail_at",
    "TailNow",
]


if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(__name__, globals(), _SOURCES)
