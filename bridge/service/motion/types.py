"""Values of the motion controller: modes, refusals, accepted motions, the active-motion records.

Kept apart from :mod:`.motion` (the controller and its thread) so the API layer and the state
message can use them without the controller.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from planner.limits.guard import Guard, GuardDecision
from planner.trajectory import JogController, JogOutput, MotionState, Plan

__all__ = [
    "MODES",
    "MOTION_MODES",
    "ATTACH_SPEED_SCALE",
    "MotionError",
    "MotionAccepted",
    "JogAccepted",
    "PlanMotion",
    "JogMotion",
    "check_mode_allows",
    "check_precedence",
    "plan_state",
    "reasons_json",
    "stability_json",
    "streamed_reference",
]

#: operating modes (thesis HITCH.md §4: automatic, manual, implement attach, transport, configuration)
MODES: tuple[str, ...] = ("auto", "manual", "attach", "transport", "config")
#: what each mode allows: "all" motion, "jog" only, or "none" (stop is always allowed)
MOTION_MODES: Mapping[str, str] = {
    "auto": "all",
    "attach": "jog",
    "manual": "none",
    "transport": "none",
    "config": "none",
}
#: jog speed scale in implement-attach mode (slow: the operator is near the hitch)
ATTACH_SPEED_SCALE = 0.25


class MotionError(ValueError):
    """A motion command refused; ``code`` is the API error code (mode, busy, ecu, bad_request)."""

    def __init__(self, code: str, message: str):
        self.code = code
        super().__init__(message)


def check_mode_allows(mode: str, what: str) -> None:
    """:class:`MotionError` ("mode") unless ``mode`` allows ``what`` (goto, preset, maneuver, jog)."""
    allowed = MOTION_MODES[mode]
    if allowed == "none" or (allowed == "jog" and what != "jog"):
        hint = "per-cylinder motion is not offered by this service" if mode == "manual" else "switch to mode 'auto'"
        raise MotionError(
            "mode", f"{what} is refused in mode {mode!r} ({'jog only' if allowed == 'jog' else 'no motion'}; {hint})"
        )


def reasons_json(decision: GuardDecision) -> dict[str, str]:
    """The guard's reasons as ``{measure: "level: sentence"}`` (the "control limited" entries)."""
    return {r.measure: f"{r.level}: {r.sentence()}" for r in decision.reasons}


def stability_json(rep) -> dict:
    """A stability report's margins as JSON: SSM, LSM [m], ESM [J], front-axle share, violations."""
    return {
        "ok": rep.ok,
        "ssm": rep.ssm,
        "lsm": rep.lsm,
        "esm": rep.esm,
        "front_axle_share": rep.front_axle_share,
        "weakest_edge": rep.weakest_edge,
        "violations": [
            {"measure": v.measure, "value": v.value, "threshold": v.threshold, "level": v.level} for v in rep.violations
        ],
    }


@dataclass(frozen=True)
class MotionAccepted:
    """A started plan motion: id, planned duration [s], its kind and the guard's decision."""

    motion_id: int
    duration: float
    kind: str
    decision: GuardDecision

    def to_json(self) -> dict:
        return {
            "accepted": True,
            "motion_id": self.motion_id,
            "duration": self.duration,
            "speed_factor": self.decision.speed_factor,
            "guard": self.decision.action,
            "limited": reasons_json(self.decision),
        }


@dataclass(frozen=True)
class JogAccepted:
    """A started or refreshed jog; ``limited`` maps a direction/measure to the limit that caps it."""

    motion_id: int
    limited: dict
    decision: GuardDecision

    def to_json(self) -> dict:
        return {
            "accepted": True,
            "motion_id": self.motion_id,
            "limited": dict(self.limited),
            "guard": self.decision.action,
            "speed_factor": self.decision.speed_factor,
        }


@dataclass
class PlanMotion:
    """A running plan (mutable record of the control thread).

    ``kind``: goto, preset, maneuver, stop, or jog (a jog braking after its TTL). Plan time 0 is
    clock time ``t0``; before ``t0`` the replaced motion ``prev`` still runs (smooth hand-over).
    """

    kind: str
    motion_id: int
    plan: Plan
    t0: float
    prev: PlanMotion | None = None
    decision: GuardDecision = field(default_factory=lambda: GuardDecision("ok"))
    label: str | None = None

    def finished(self, t: float) -> bool:
        return t - self.t0 >= self.plan.duration

    def limited(self) -> dict[str, str]:
        """What slows this plan (a guard caution or the end-stop zone), for the state's ``limited``."""
        return reasons_json(self.decision) if self.decision.action == "scaled" else {}


@dataclass
class JogMotion:
    """A live jog: requested rates [m/s, rad/s] until clock time ``expires`` (dead-man)."""

    motion_id: int
    jog: JogController
    rates: np.ndarray
    expires: float
    t_state: float = 0.0  # clock time of ``jog.state`` (its last step)
    limited: dict = field(default_factory=dict)
    reported: set = field(default_factory=set)  # limits already announced by a limit_reached event
    decision: GuardDecision = field(default_factory=lambda: GuardDecision("ok"))

    def refresh(self, guard: Guard, rates: np.ndarray, expires: float) -> JogAccepted:
        """A new command: rates [m/s, rad/s] until clock time ``expires``; checked ahead by the guard."""
        self.rates, self.expires = np.asarray(rates, float), float(expires)
        allowed, self.decision = guard.check_jog(self.jog.state, self.rates)
        _, flags = self.jog.clipped_rates(allowed)
        self.limited = {**flags, **reasons_json(self.decision)}
        return JogAccepted(self.motion_id, dict(self.limited), self.decision)

    def step(self, guard: Guard) -> tuple[JogOutput, list[dict]]:
        """One control cycle: the rates re-checked ahead by the guard, then the jerk-limited step.
        Returns the step and a ``limit_reached`` event naming each limit that newly caps the jog
        (a workspace face, a stability measure ahead, an end-stop zone)."""
        allowed, self.decision = guard.check_jog(self.jog.state, self.rates)
        self.jog.command(allowed, 1.0)  # the dead-man TTL is ours (``expires``), not the controller's
        out = self.jog.step()
        self.limited = {**out.limited, **reasons_json(self.decision)}
        new = {k: v for k, v in self.limited.items() if k not in self.reported}
        self.reported = set(self.limited)
        events = [{"event": "limit_reached", "motion_id": self.motion_id, "limits": new}] if new else []
        return out, events


def check_precedence(active: PlanMotion | JogMotion | None, now: float) -> None:
    """:class:`MotionError` ("busy") when ``active`` outranks a new goto/preset/maneuver: a stop
    until it is at rest, a jog while its command is live (stop > jog > goto)."""
    if isinstance(active, PlanMotion) and active.kind == "stop":
        raise MotionError(
            "busy",
            f"a stop is in progress (motion {active.motion_id}); new motion is refused until the hitch is at rest",
        )
    if isinstance(active, JogMotion) and now < active.expires:
        raise MotionError(
            "busy",
            f"a jog command is live (motion {active.motion_id}, {active.expires - now:.2f} s "
            "left); jog has precedence over goto",
        )


def plan_state(m: PlanMotion, t: float) -> MotionState:
    """Pose-space state of a plan motion at clock time ``t`` (its predecessor's before ``t0``)."""
    if m.prev is not None and t < m.t0:
        return plan_state(m.prev, t)
    return m.plan.state_at(t - m.t0)


def streamed_reference(shaper, m: PlanMotion | JogMotion | None, ref, now: float) -> np.ndarray:
    """The actuator reference to stream for the planned ``ref`` = (state, q, q̇) of motion ``m``:
    feed-forward through the unit loops (:class:`bridge.link.unit_loop.FeedforwardShaper`) for a plan
    (looking ahead in it) or a jog (its rates and acceleration now); the final reference itself while holding."""
    if isinstance(m, PlanMotion):
        return shaper.for_plan(lambda t: plan_state(m, t), now, ref[1], ref[2])
    if isinstance(m, JogMotion):
        return shaper.for_state(ref[0], ref[1], ref[2])
    return ref[1]
