"""Values of the motion controller: modes, refusals, accepted motions, the active-motion records.

Kept apart from :mod:`bridge.service.motion.controller` (the controller and its thread) so the
API layer and the state message can use them without the controller.

Every value the service sends as JSON has a ``to_json()`` method returning a JSON-ready dict
(:class:`MotionAccepted`, :class:`JogAccepted`, :class:`ManeuverAccepted`, :class:`PlanPreview`,
:class:`StabilityMargins`); pose and actuator vectors become dicts by name through
:func:`pose_dict` and :func:`actuator_dict`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bridge.link.count_tail import CountTail
from bridge.link.unit_loop import FeedforwardShaper
from bridge.service.motion.ground_watch import GroundWatch
from planner.errors import HitchInputError
from planner.limits.guard import Guard, GuardDecision, GuardedPlan, GuardRefusal
from planner.limits.implement_limits import ImplementLimits
from planner.limits.stability import StabilityReport, StabilityViolation
from planner.limits.tractor import ImplementRecord
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES
from planner.trajectory import JogController, JogOutput, MotionState, Plan, PlanError
from planner.trajectory.track import SeqFilter, TrackFollower, TrackOutput

__all__ = [
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
    "TrackMotion",
    "TrackAccepted",
    "TRACK_FRAMES",
    "TRACK_GUARD_EVERY",
    "ActiveMotion",
    "Reference",
    "Fault",
    "FaultAck",
    "SELF_CLEARING_FAULTS",
    "FAULT_CLEAR_AFTER_S",
    "DEFAULT_DEADLINE_S",
    "actuator_dict",
    "check_mode_allows",
    "check_precedence",
    "guard_limits",
    "plan_state",
    "running_at",
    "tail_at",
    "TailNow",
    "pose_dict",
    "implement_selected_event",
    "streamed_reference",
]

#: operating modes (thesis §4, see docs/source_thesis.md: automatic, manual, implement attach, transport, configuration)
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

#: faults that clear themselves once the data they are about is fresh again (``docs/faults.md``);
#: every other fault — including names this version does not know — latches until ``faults/ack``
SELF_CLEARING_FAULTS: frozenset[str] = frozenset({"stale_measurement", "ecu_heartbeat"})
#: how long the data must be fresh without a break before a self-clearing fault clears [s]
FAULT_CLEAR_AFTER_S = 0.25
#: the deadline of a motion request that names none: it must start moving within this [s]
DEFAULT_DEADLINE_S = 1.0

#: one ``<prefix>/events`` message (a JSON-ready dict with an ``event`` name)
Event = dict[str, Any]


class MotionError(HitchInputError):
    """A motion command refused; ``code`` is the API error code (mode, busy, ecu, bad_request)."""

    def __init__(self, code: str, message: str):
        self.code = code
        super().__init__(message)


@dataclass(frozen=True)
class Fault:
    """A fault as the motion controller holds it: its ``name`` (a :class:`bridge.link.state.LinkFaults`
    field, or ``internal``), the ``reason`` sentence, whether it ``latches`` until acknowledged, and
    the clock time it was raised [s]."""

    name: str
    reason: str
    latches: bool
    since: float

    def to_json(self) -> dict[str, Any]:
        return {"fault": self.name, "reason": self.reason, "latches": self.latches, "since": self.since}


@dataclass(frozen=True)
class FaultAck:
    """The answer to ``faults/ack``: the latched faults ``acknowledged`` (cleared) and the faults
    still held afterwards (self-clearing ones whose data is not fresh yet)."""

    acknowledged: tuple[str, ...]
    remaining: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {"acknowledged": list(self.acknowledged), "faults": list(self.remaining)}


def pose_dict(p: Iterable[float]) -> dict[str, float]:
    """A controlled pose (or its rates) by name: x, z [m]; roll, pitch [rad] (per second for rates)."""
    return dict(zip(CONTROLLED_POSE_NAMES, map(float, p), strict=True))


def implement_selected_event(implement: ImplementRecord | None, limits: ImplementLimits) -> Event:
    """The ``implement_selected`` event: the implement the guards plan with (``implement`` null: none) and its
    limits (``docs/implements.md``). Posted once the change is recorded everywhere a client reads it back
    (``implements/list``, ``presets/list``): the terminal asks those on this event."""
    return {
        "event": "implement_selected",
        "implement": None if implement is None else implement.name,
        **limits.to_json(),
    }


def actuator_dict(q: Iterable[float]) -> dict[str, float]:
    """Actuator coordinates by name: lift [rad]; tilt, top, left, right [m]."""
    return dict(zip(ACTUATOR_NAMES, map(float, q), strict=True))


def check_mode_allows(mode: str, what: str) -> None:
    """:class:`MotionError` ("mode") unless ``mode`` allows ``what`` (goto, preset, maneuver, jog)."""
    allowed = MOTION_MODES[mode]
    if allowed == "none" or (allowed == "jog" and what != "jog"):
        hint = "per-cylinder motion is not offered by this service" if mode == "manual" else "switch to mode 'auto'"
        raise MotionError(
            "mode", f"{what} is refused in mode {mode!r} ({'jog only' if allowed == 'jog' else 'no motion'}; {hint})"
        )


def guard_limits(decision: GuardDecision) -> dict[str, str]:
    """The guard's reasons as ``{measure: "level: sentence"}`` (the "control limited" entries)."""
    return {r.measure: f"{r.level}: {r.sentence()}" for r in decision.reasons}


def newly_limited(limited: Mapping[str, str], decision: GuardDecision, reported: dict[str, str]) -> dict[str, str]:
    """The entries of ``limited`` (a step's limits: the follower's or jog's flags and :func:`guard_limits`)
    whose limit is new since ``reported``, which is updated. A limit is its entry's text, but a guard
    reason's is its measure and level: its sentence carries the value of the moment (an end-stop factor
    0.4616, 0.4696, … every cycle), which announced the same limit again ten times a second."""
    levels = {r.measure: r.level for r in decision.reasons}
    ids = {k: levels.get(k, v) for k, v in limited.items()}
    new = {k: limited[k] for k, i in ids.items() if reported.get(k) != i}
    reported.clear()
    reported.update(ids)
    return new


@dataclass(frozen=True)
class StabilityMargins:
    """A stability report's margins as the service shows them: SSM, LSM [m], ESM [J], the
    front-axle share of the weight, the weakest edge and the thresholds crossed."""

    ok: bool
    ssm: float
    lsm: float
    esm: float
    front_axle_share: float
    weakest_edge: str
    violations: tuple[StabilityViolation, ...] = ()

    @classmethod
    def of(cls, rep: StabilityReport) -> StabilityMargins:
        return cls(rep.ok, rep.ssm, rep.lsm, rep.esm, rep.front_axle_share, rep.weakest_edge, tuple(rep.violations))

    def to_json(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "ssm": self.ssm,
            "lsm": self.lsm,
            "esm": self.esm,
            "front_axle_share": self.front_axle_share,
            "weakest_edge": self.weakest_edge,
            "violations": [
                {"measure": v.measure, "value": v.value, "threshold": v.threshold, "level": v.level}
                for v in self.violations
            ],
        }


def _stability(decision: GuardDecision) -> dict[str, Any] | None:
    return None if decision.worst is None else StabilityMargins.of(decision.worst).to_json()


@dataclass(frozen=True)
class PlanPreview:
    """The answer to a ``plan`` request: the guarded plan a goto would run now, or why there is none.

    ``duration`` [s] and ``goal`` (the full end pose) when planned; ``refused``: the refusal's
    sentence otherwise; ``decision``: the guard's (None when the planner refused before the guard).
    ``count_approach_s``: how much of ``duration`` the profile's count approach takes after the plan (0: none;
    :mod:`bridge.link.count_tail`), so the preview lasts as long as the goto would.
    """

    ok: bool
    duration: float | None = None
    goal: Mapping[str, float] | None = None
    decision: GuardDecision | None = None
    refused: str | None = None
    count_approach_s: float = 0.0

    @classmethod
    def planned(cls, gp: GuardedPlan, tail: CountTail | None = None) -> PlanPreview:
        """The preview of ``gp`` with the count approach ``tail`` after it (None: the goto ends as its plan)."""
        end = gp.plan.state_at(gp.plan.duration).position
        extra = 0.0 if tail is None else tail.approach.duration_s
        return cls(True, gp.plan.duration + extra, pose_dict(end), gp.decision, count_approach_s=extra)

    @classmethod
    def refusal(cls, exc: PlanError) -> PlanPreview:
        """A plan the planner (:class:`PlanError`) or the guard (:class:`GuardRefusal`) refused."""
        return cls(False, decision=exc.decision if isinstance(exc, GuardRefusal) else None, refused=str(exc))

    def to_json(self) -> dict[str, Any]:
        d = self.decision
        reasons = [] if d is None else [r.to_json() for r in d.reasons]
        stability = None if d is None else _stability(d)
        if not self.ok or d is None:
            return {"ok": False, "duration": None, "refused": self.refused, "reasons": reasons, "stability": stability}
        return {
            "ok": True,
            "duration": self.duration,
            "count_approach_s": self.count_approach_s,
            "goal": None if self.goal is None else dict(self.goal),
            "guard": d.action,
            "speed_factor": d.speed_factor,
            "reasons": reasons,
            "stability": stability,
        }


@dataclass(frozen=True)
class MotionAccepted:
    """A started plan motion: id, planned duration [s], its kind and the guard's decision."""

    motion_id: int
    duration: float
    kind: str
    decision: GuardDecision

    def to_json(self) -> dict[str, Any]:
        return {
            "accepted": True,
            "motion_id": self.motion_id,
            "duration": self.duration,
            "speed_factor": self.decision.speed_factor,
            "guard": self.decision.action,
            "limited": guard_limits(self.decision),
        }


@dataclass(frozen=True)
class JogAccepted:
    """A started or refreshed jog; ``limited`` maps a direction/measure to the limit that caps it."""

    motion_id: int
    limited: Mapping[str, str]
    decision: GuardDecision

    def to_json(self) -> dict[str, Any]:
        return {
            "accepted": True,
            "motion_id": self.motion_id,
            "limited": dict(self.limited),
            "guard": self.decision.action,
            "speed_factor": self.decision.speed_factor,
        }


@dataclass(frozen=True)
class ManeuverAccepted:
    """A started maneuver: its id, planned duration [s] (motions and waits), its script's step count (as
    ``maneuvers/save`` and ``list`` give it), how many of them run (``actions``: a ``speed`` step only sets
    the scale of those after it) and name. In JSON the id is ``maneuver_id`` (the id of the maneuver's
    events) and, for older clients, also ``motion_id``: it names no motion (each step is a motion of its
    own; wait for the maneuver with :meth:`~bridge.service.client.HitchClient.wait_maneuver`)."""

    motion_id: int
    duration: float
    steps: int
    name: str
    actions: int | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "accepted": True,
            "maneuver_id": self.motion_id,
            "motion_id": self.motion_id,
            "duration": self.duration,
            "steps": self.steps,
            "actions": self.steps if self.actions is None else self.actions,
            "maneuver": self.name,
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
    announced: bool = False  # its motion_finished event is out
    #: the profile's count approach after the plan (the via, then the final counts; None: the plan alone)
    tail: CountTail | None = None

    @property
    def duration(self) -> float:
        """The plan and its count approach [s]."""
        return self.plan.duration + (0.0 if self.tail is None else self.tail.approach.duration_s)

    def finished(self, t: float) -> bool:
        return t - self.t0 >= self.duration

    def in_tail(self, t: float) -> bool:
        """Whether clock time ``t`` lies in the count approach after the plan."""
        return self.tail is not None and t - self.t0 >= self.plan.duration

    def limited(self) -> dict[str, str]:
        """What slows this plan (a guard caution or the end-stop zone), for the state's ``limited``."""
        return guard_limits(self.decision) if self.decision.action == "scaled" else {}


@dataclass
class JogMotion:
    """A live jog: requested rates [m/s, rad/s] until clock time ``expires`` (dead-man)."""

    motion_id: int
    jog: JogController
    rates: np.ndarray
    expires: float
    t_state: float = 0.0  # clock time of ``jog.state`` (its last step)
    ff_last: tuple[float, np.ndarray] | None = None  # (clock time, pose acceleration) of the last streamed state
    limited: dict[str, str] = field(default_factory=dict)
    #: limits already announced by a limit_reached event (key → limit, :func:`newly_limited`: a key whose limit
    #: changes, e.g. from the jog speed limit to the workspace face, is announced again)
    reported: dict[str, str] = field(default_factory=dict)
    decision: GuardDecision = field(default_factory=lambda: GuardDecision("ok"))
    #: who sends the live command (the request's user; None: an anonymous client): while it is live a jog of
    #: another is refused (:meth:`MotionController.jog`)
    holder: str | None = None
    #: what the mode caps in the command's rates (``{"z+": "mode:attach"}``), named in the reply and, while it
    #: lasts, in the state (the state's "Control limited" missed attach mode's quarter speed: a terminal trial)
    caps: dict[str, str] = field(default_factory=dict)

    def refresh(self, guard: Guard, rates: np.ndarray, expires: float) -> JogAccepted:
        """A new command: rates [m/s, rad/s] until clock time ``expires``; checked ahead by the guard."""
        self.rates, self.expires = np.asarray(rates, float), float(expires)
        allowed, self.decision = self._checked(guard)
        _, flags = self.jog.clipped_rates(allowed)
        self.limited = {**self.caps, **self._speed_flags(), **flags, **guard_limits(self.decision)}
        return JogAccepted(self.motion_id, dict(self.limited), self.decision)

    def step(self, guard: Guard) -> tuple[JogOutput, list[Event]]:
        """One control cycle: the rates re-checked ahead by the guard, then the jerk-limited step.
        Returns the step and a ``limit_reached`` event naming each limit that newly caps the jog
        (a workspace face, a stability measure ahead, an end-stop zone)."""
        allowed, self.decision = self._checked(guard)
        self.jog.command(allowed, 1.0)  # the dead-man TTL is ours (``expires``), not the controller's
        out = self.jog.step()
        self.limited = {**self.caps, **self._speed_flags(), **out.limited, **guard_limits(self.decision)}
        new = newly_limited(self.limited, self.decision, self.reported)
        events: list[Event] = [{"event": "limit_reached", "motion_id": self.motion_id, "limits": new}] if new else []
        return out, events

    def _speed_flags(self) -> dict[str, str]:
        """The jog speed limits the rates asked exceed (none while the guard refuses the jog: nothing moves)."""
        return {} if self.decision.action == "refused" else self.jog.speed_flags(self.rates)

    def _checked(self, guard: Guard) -> tuple[np.ndarray, GuardDecision]:
        """The guard's rates and decision for the rates asked within the jog's speed limits: the rates the jog can
        run (judged as asked, a jog asked at 1 m/s was judged at the workspace face 1 s ahead: an operator's trial
        read a caution's 0.8 lost, the jog ran at full speed). Every cycle with its way (:meth:`Guard.check_jog`:
        ~0.6 ms near a limit; judged every 5th cycle, a refusal on the way was dropped at the next and the jog went
        into the keep-out it had been refused for, a review)."""
        v = self.jog.limits.velocity
        return guard.check_jog(self.jog.state, np.clip(self.rates, -v, v))


#: the frames a track session's setpoints may be given in (``docs/tracking.md``)
TRACK_FRAMES: tuple[str, ...] = ("tractor", "level", "ground")
#: a track session's stability check 1 s ahead runs every this many control cycles (it costs ~0.4 ms)
TRACK_GUARD_EVERY = 5


@dataclass(frozen=True)
class TrackAccepted:
    """A started track session: its ``session`` id (setpoints name it), the motion id, frame, DOFs, TTL [s]."""

    session: int
    motion_id: int
    frame: str
    dofs: tuple[str, ...]
    ttl_s: float

    def to_json(self) -> dict[str, Any]:
        return {
            "accepted": True,
            "session": self.session,
            "motion_id": self.motion_id,
            "frame": self.frame,
            "dof": list(self.dofs),
            "ttl_ms": round(self.ttl_s * 1000.0),
        }


@dataclass
class TrackMotion:
    """A live track session (streamed setpoints followed online; mutable record of the control thread).

    ``frame``: what the setpoints mean (:data:`TRACK_FRAMES`); ``seq`` drops old and out-of-order
    setpoints; ``reason`` says why the session ends once the follower brakes (stale, stop, guard).
    """

    motion_id: int
    session: int
    follower: TrackFollower
    frame: str
    t_state: float = 0.0  # clock time of ``follower.state`` (its last step)
    ff_last: tuple[float, np.ndarray] | None = None  # (clock time, pose acceleration) of the last streamed state
    seq: SeqFilter = field(default_factory=SeqFilter)
    limited: dict[str, str] = field(default_factory=dict)
    reported: dict[str, str] = field(default_factory=dict)  # as JogMotion.reported
    decision: GuardDecision = field(default_factory=lambda: GuardDecision("ok"))
    reason: str | None = None
    accepted: int = 0  # setpoints taken
    rejected: int = 0  # setpoints refused (bad values, frame sensor missing)
    last_rejection: str | None = None
    cycles: int = 0
    #: a ``track/stop`` that waits for the client's last setpoint: (its seq, clock time [s] after which
    #: the follower brakes anyway — the setpoint was lost on the way); None: no stop waits
    stop_after: tuple[int, float] | None = None
    #: frame ``ground``: whether its ground-distance reading stays stuck while the hitch moves
    ground_watch: GroundWatch = field(default_factory=GroundWatch)
    ignored_announced_s: float = -math.inf  # its last track_setpoint_ignored event (one a second, per session)

    @property
    def dofs(self) -> tuple[str, ...]:
        return self.follower.dofs

    def stop_after_seq(self, last_seq: int | None, now: float) -> bool:
        """``track/stop`` for a client that sent setpoints up to ``last_seq``: True when the follower
        brakes now (nothing of the client's is still on the way), False when the stop waits for
        ``last_seq`` — at most one time-to-live (:meth:`take_stop`, :meth:`step`). A streamed setpoint
        (a Zenoh put) and the stop (a query) travel different paths and may arrive in either order."""
        seen = self.seq.last
        if last_seq is None or self.ending or (seen is not None and seen >= last_seq):
            self._brake_now()
            return True
        self.stop_after = (int(last_seq), now + self.follower.ttl_s)
        return False

    def take_stop(self, seq: int) -> None:
        """After setpoint ``seq`` was handled (taken or refused): the waiting stop brakes once it came."""
        if self.stop_after is not None and seq >= self.stop_after[0]:
            self._brake_now()

    def _brake_now(self) -> None:
        """The stop (waiting or not) brakes from this cycle on."""
        self.stop_after = None
        self.follower.stop()

    @property
    def ending(self) -> bool:
        """Braking to its end (stale stream, ``track/stop``, a guard refusal): a goto may replace it."""
        return self.follower.stale or self.follower.stopping

    def step(self, guard: Guard, now: float) -> tuple[TrackOutput, list[Event]]:
        """One control cycle of the follower. Returns the step and a ``limit_reached`` event for newly
        hit limits. The session's first step is preceded by the guard's look-ahead (:meth:`look_ahead`);
        every later one runs after the cycle's reference was sent."""
        self.cycles += 1
        events: list[Event] = []
        if self.stop_after is not None and now >= self.stop_after[1]:  # the last setpoint never came
            self._brake_now()
        if self.cycles == 1:
            self._look_ahead(guard)
        out = self.follower.step(now)
        self.t_state = now
        self.limited = {**out.limited, **guard_limits(self.decision)}
        new = newly_limited(self.limited, self.decision, self.reported)
        if new:
            events.append({"event": "limit_reached", "motion_id": self.motion_id, "limits": new})
        if out.stale and self.reason is None:
            self.reason = f"stale: no setpoint within {self.follower.ttl_s * 1000:.0f} ms"
        return out, events

    def look_ahead(self, guard: Guard) -> None:
        """After a cycle's reference is sent: every :data:`TRACK_GUARD_EVERY`-th cycle the stability 1 s
        ahead along the follower's current rates (:meth:`Guard.check_jog`), for the next step. A motion
        the guard refuses (a hard stability or keep-out limit ahead) ends the session, braking from
        the next step on.

        The check sees the state the next step starts from, exactly as if it ran at the start of
        that step, but a setpoint that arrives meanwhile reaches the bus without waiting for it
        (it costs about a millisecond; ``bench/track_cycle_bench.py``)."""
        if self.cycles % TRACK_GUARD_EVERY == 0:
            self._look_ahead(guard)

    def _look_ahead(self, guard: Guard) -> None:
        if self.ending:
            return
        rates = self.follower.guard_rates(1.0)
        # the end 1 s ahead only, as before the jog's way was judged: with the way (~0.6-1 ms) the track cycle's p99
        # rose from 0.76-0.98 ms to 1.76-2.06 ms against its 1 ms target (bench/track_cycle_bench.py); the follower
        # clips to the workspace itself, keep-outs on a session's way are not looked at (left open, docs/tracking.md)
        _, self.decision = guard.check_jog(self.follower.state, rates, along_path=False)
        if self.decision.action == "refused":  # a hard limit ahead (caution or an end-stop zone: reported)
            self.reason = "guard: " + "; ".join(guard_limits(self.decision).values() or ["motion refused ahead"])
            self.follower.stop()

    def progress(self) -> dict[str, Any]:
        """The state message's ``track`` entry."""
        sp = self.follower.setpoint
        return {
            "session": self.session,
            "frame": self.frame,
            "dof": list(self.dofs),
            "setpoints": self.accepted,
            "rejected": self.rejected,
            "ignored_seq": self.seq.ignored,
            "last_seq": self.seq.last,
            "stale": self.follower.stale,
            "ending": self.ending,
            "target": None if sp is None else pose_dict(sp.position),
            "control_limited": dict(self.limited),
            "last_rejection": self.last_rejection,
        }


#: the motion the controller runs (one at a time)
ActiveMotion = PlanMotion | JogMotion | TrackMotion


@dataclass(frozen=True)
class Reference:
    """What is streamed for one cycle: the commanded pose-space ``state``, its ``actuators`` q
    (lift [rad], the others [m]) and their ``rates`` q̇ (per second)."""

    state: MotionState
    actuators: np.ndarray
    rates: np.ndarray


def check_precedence(active: ActiveMotion | None, now: float) -> None:
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
    if isinstance(active, TrackMotion) and not active.ending:
        raise MotionError(
            "busy",
            f"track session {active.session} is active (motion {active.motion_id}); send track/stop first "
            "(track has precedence over goto)",
        )


def plan_state(m: PlanMotion, t: float) -> MotionState:
    """Pose-space state of a plan motion at clock time ``t`` (its predecessor's before ``t0``)."""
    if m.prev is not None and t < m.t0:
        return plan_state(m.prev, t)
    return m.plan.state_at(t - m.t0)


def running_at(m: PlanMotion, t: float) -> PlanMotion:
    """The plan motion that runs at clock time ``t``: ``m``, or before its ``t0`` the one it replaced (and so on
    back: a goto replaced within another's lead)."""
    while m.prev is not None and t < m.t0:
        m = m.prev
    return m


@dataclass(frozen=True)
class TailNow:
    """A count approach running now: the ``actuators`` it streams (SI) and ``state``, at rest at their pose (the
    plan's end where the pose is not known): where the hitch rests and whatever follows starts."""

    actuators: np.ndarray
    state: MotionState


def tail_at(m: PlanMotion, t: float) -> TailNow | None:
    """The count approach of the motion running at ``t`` (:func:`running_at`: ``m``, or the one it replaces in
    its lead) when that motion is in it (also after its end: it holds the final counts), else None."""
    run = running_at(m, t)
    if run.tail is None or not run.in_tail(t):
        return None
    after = t - run.t0 - run.plan.duration
    pose = run.tail.pose_at(after)
    state = MotionState.at_rest(plan_state(run, t).position if pose is None else pose)
    return TailNow(run.tail.actuators_at(after), state)


FF_JERK_GAP_S = 0.1
"""Largest gap [s] between two streamed states whose accelerations give the feed-forward's jerk."""


def streamed_reference(shaper: FeedforwardShaper, m: ActiveMotion | None, ref: Reference, now: float) -> np.ndarray:
    """The actuator reference to stream for the planned ``ref`` of motion ``m``: feed-forward
    through the unit loops (:class:`bridge.link.unit_loop.FeedforwardShaper`) for a plan (looking
    ahead in it) or a jog or track session (its rates, acceleration and jerk now: the jerk from the
    accelerations of this and the previous streamed state, at most :data:`FF_JERK_GAP_S` apart); the
    final reference itself while holding."""
    if isinstance(m, PlanMotion):
        in_tail = tail_at(m, now)  # the count approach (also of a goto a new plan replaces): whole counts
        if in_tail is not None:
            return in_tail.actuators
        return shaper.for_plan(lambda t: plan_state(m, t), now, ref.actuators, ref.rates)
    if isinstance(m, (JogMotion, TrackMotion)):
        acc = np.asarray(ref.state.acceleration, float)
        jerk = None
        if m.ff_last is not None and 0.0 < now - m.ff_last[0] <= FF_JERK_GAP_S:
            jerk = (acc - m.ff_last[1]) / (now - m.ff_last[0])
        m.ff_last = (now, acc.copy())
        return shaper.for_state(ref.state, ref.actuators, ref.rates, jerk=jerk)
    return ref.actuators
