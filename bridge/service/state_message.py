"""The ``<prefix>/state`` message: one :class:`StateMessage` per control cycle, sent as its ``to_json()``.

Fields: ``t`` (Unix time [s]), ``clock`` (link clock [s]), ``seq``; ``pose`` and ``actuators``
as measured over CAN (forward kinematics of the ECU's readings; None before the first);
``reference`` (the commanded pose x, z, roll, pitch and actuators, None when nothing is
streamed); ``velocity`` (commanded pose rates [m/s, rad/s]); ``mode``, ``moving``,
``motion_id``, ``motion`` (kind); ``limited`` (what caps the motion → the limit's name: the
"Control limited" of the thesis terminal); ``kinematic_margin`` (time to the nearest limit at the
commanded velocity, :mod:`planner.limits.kinematic_margin`); ``stability`` (tractor + implement
margins at the measured pose, :class:`~bridge.service.motion.types.StabilityMargins`); ``ecu``
(:class:`EcuSummary`: ``online``, ``watchdog`` tripped, ``controllers_on``, the ``faults`` the
motion controller holds and their reasons, ``ack_required`` (those that latch until
``faults/ack``), the link's own latched flags ``link_faults``, heartbeat, streaming, reference
counters, feed-forward); ``maneuver`` (:class:`~bridge.service.maneuvers.slot.ManeuverProgress`);
``goal`` (the running plan's end: ``pose`` and ``actuators`` of its last verified sample, for a
goto, preset, raise/return or maneuver step; None otherwise, :func:`plan_goal`).

At rest the guard's evaluations (kinematic margin, stability) do not change: an
:class:`EvaluationCache` keeps the last ones and recomputes only when the measured counts or the
reference change.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from bridge.link.state import LinkState, LinkStatus
from bridge.link.unit_loop import FeedforwardShaper
from bridge.service.maneuvers.slot import ManeuverProgress
from bridge.service.motion.types import Event, Fault, Reference, StabilityMargins, actuator_dict, pose_dict
from planner.limits.guard import Guard
from planner.limits.kinematic_margin import KinematicMargin
from planner.model.types import CONTROLLED_POSE_NAMES, KinematicsError

__all__ = [
    "EvaluationCache",
    "EcuSummary",
    "FeedforwardStatus",
    "StateMessage",
    "build_state_message",
    "fault_transition",
    "link_problem",
    "plan_goal",
]

_T = TypeVar("_T")


def _safe(fn: Callable[[], _T]) -> _T | None:
    try:
        return fn()
    except (ValueError, KinematicsError):  # a measured pose the stability model cannot take
        return None


def plan_goal(kind: str, plan: Any) -> dict[str, Any] | None:
    """Where a running plan ends: ``{"pose", "actuators"}`` of its last verified sample (the exact
    endpoint, :func:`planner.trajectory.plan.sample_times`); None for plans without samples (stops,
    a jog braking) — they have no target to show."""
    sp = getattr(plan, "setpoints", None)
    if kind in ("stop", "jog") or sp is None or len(sp.t) == 0:
        return None
    return {"pose": pose_dict(plan.state_at(plan.duration).position), "actuators": actuator_dict(sp.actuators[-1])}


def link_problem(status: LinkStatus, now: float, stale_after_s: float) -> str | None:
    """Why motion cannot start now (None: it can). Latched faults whose causes are gone do not
    count: the first reference of a fresh command re-arms the link, which refuses it if a cause
    is still present."""
    if not status.claimed:
        return "the CAN link has not claimed its address yet"
    if status.state is None:
        return "no measurement from the cylinder ECU yet"
    age = status.state.age_s(now)
    if age > stale_after_s:
        return f"the ECU measurements are {age:.3f} s old (limit {stale_after_s:g} s)"
    if not status.heartbeat.healthy:
        return f"the ECU heartbeat is {status.heartbeat.state.value}"
    return None


class EvaluationCache:
    """One remembered value per slot (``margin``, ``stability``): :meth:`get` recomputes only when
    the key changes. ``evaluations`` counts the computations (idle cost tests)."""

    def __init__(self) -> None:
        self._slots: dict[str, tuple[Hashable, Any]] = {}
        self.evaluations = 0

    def get(self, slot: str, key: Hashable, fn: Callable[[], _T]) -> _T:
        hit = self._slots.get(slot)
        if hit is not None and hit[0] == key:
            return hit[1]
        value = fn()
        self.evaluations += 1
        self._slots[slot] = (key, value)
        return value


def fault_transition(
    reported: tuple[str, ...], status: LinkStatus, events: list[Event]
) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Compare the link's latched faults with those ``reported`` before; append a ``fault`` event
    when new ones appeared, ``fault_cleared`` when all are gone. Returns (faults now, new faults)."""
    faults = status.faults.active() if status.faults.any else ()
    new = tuple(f for f in faults if f not in reported)
    if new:
        events.append({"event": "fault", "faults": list(faults), "message": "; ".join(status.faults.reasons)})
    elif not faults and reported:
        events.append({"event": "fault_cleared"})
    return faults, new


@dataclass(frozen=True)
class FeedforwardStatus:
    """Whether the unit loops' feed-forward is streamed, and how many references the hard-limit
    check made it pull back towards the plan (a count)."""

    enabled: bool
    pulled_back: int

    def to_json(self) -> dict[str, Any]:
        return {"enabled": self.enabled, "pulled_back": self.pulled_back}


@dataclass(frozen=True)
class EcuSummary:
    """The cylinder ECU and the link as the terminal shows them (the state's ``ecu``)."""

    online: bool
    watchdog: bool
    controllers_on: bool
    faults: tuple[str, ...]
    fault_reasons: tuple[str, ...]
    heartbeat: str
    streaming: bool
    measurement_age_s: float | None
    references_sent: int
    references_refused: int
    feedforward: FeedforwardStatus | None = None
    ack_required: tuple[str, ...] = ()
    link_faults: tuple[str, ...] = ()

    @classmethod
    def of(
        cls,
        status: LinkStatus,
        now: float,
        stale_after_s: float,
        shaper: FeedforwardShaper | None = None,
        faults: Sequence[Fault] | None = None,
    ) -> EcuSummary:
        """From the link's ``status`` at clock time ``now`` [s] and its measurement age limit [s];
        ``faults``: what the motion controller holds (None: the link's latched flags)."""
        ls = status.state
        age = ls.age_s(now) if ls is not None else math.inf
        c = status.counters
        link_faults = tuple(status.faults.active())
        return cls(
            online=link_problem(status, now, stale_after_s) is None,
            watchdog=bool(ls is not None and ls.system.watchdog_tripped),
            controllers_on=bool(ls is not None and ls.system.controllers_on),
            faults=link_faults if faults is None else tuple(f.name for f in faults),
            fault_reasons=tuple(status.faults.reasons) if faults is None else tuple(f.reason for f in faults),
            heartbeat=status.heartbeat.state.value,
            streaming=status.streaming,
            measurement_age_s=age if math.isfinite(age) else None,
            references_sent=c.references_tx,
            references_refused=c.references_refused,
            feedforward=None if shaper is None else FeedforwardStatus(shaper.enabled, shaper.pulled_back),
            ack_required=() if faults is None else tuple(f.name for f in faults if f.latches),
            link_faults=link_faults,
        )

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "online": self.online,
            "watchdog": self.watchdog,
            "controllers_on": self.controllers_on,
            "faults": list(self.faults),
            "fault_reasons": list(self.fault_reasons),
            "ack_required": list(self.ack_required),
            "link_faults": list(self.link_faults),
            "heartbeat": self.heartbeat,
            "streaming": self.streaming,
            "measurement_age_s": self.measurement_age_s,
            "references_sent": self.references_sent,
            "references_refused": self.references_refused,
        }
        if self.feedforward is not None:
            out["feedforward"] = self.feedforward.to_json()
        return out


@dataclass(frozen=True)
class StateMessage:
    """One cycle's state (see the module docstring); ``measured`` is the link's newest state,
    ``reference`` what is being streamed (None: nothing)."""

    t: float
    clock: float
    seq: int
    mode: str
    motion: str | None
    motion_id: int | None
    limited: Mapping[str, str]
    measured: LinkState | None
    reference: Reference | None
    kinematic_margin: KinematicMargin | None
    stability: StabilityMargins | None
    ecu: EcuSummary
    maneuver: ManeuverProgress | None
    track: Mapping[str, Any] | None = None  # the live track session (TrackMotion.progress())
    goal: Mapping[str, Any] | None = None  # the running plan's end pose and actuators (plan_goal)
    work: Mapping[str, Any] | None = None  # work control (bridge.service.work.WorkControl.progress())

    def to_json(self) -> dict[str, Any]:
        ls, ref = self.measured, self.reference
        return {
            "t": self.t,
            "clock": self.clock,
            "seq": self.seq,
            "mode": self.mode,
            "moving": self.motion is not None,
            "motion_id": self.motion_id,
            "motion": self.motion,
            "limited": dict(self.limited),
            "pose": None if ls is None else ls.pose.as_dict(),
            "actuators": None if ls is None else ls.actuators.as_dict(),
            # the ECU's readings as received [AD counts], before the profile's AD map: what a commissioning
            # engineer writes into a measurement file (docs/commissioning.md); the lift's recovered from the
            # rear hitch position
            "actuator_counts": None if ls is None else actuator_dict(ls.counts),
            "reference": None
            if ref is None
            else {"pose": pose_dict(ref.state.position), "actuators": actuator_dict(ref.actuators)},
            "velocity": dict.fromkeys(CONTROLLED_POSE_NAMES, 0.0) if ref is None else pose_dict(ref.state.velocity),
            "kinematic_margin": None if self.kinematic_margin is None else self.kinematic_margin.to_json(),
            "stability": None if self.stability is None else self.stability.to_json(),
            "ecu": self.ecu.to_json(),
            "maneuver": None if self.maneuver is None else self.maneuver.to_json(),
            "track": None if self.track is None else dict(self.track),
            "goal": None if self.goal is None else dict(self.goal),
            "work": None if self.work is None else dict(self.work),
        }


def build_state_message(
    *,
    seq: int,
    now: float,
    status: LinkStatus,
    stale_after_s: float,
    guard: Guard,
    mode: str,
    motion_kind: str | None,
    motion_id: int | None,
    reference: Reference | None,
    limited: Mapping[str, str],
    maneuver: ManeuverProgress | None,
    feedforward: FeedforwardShaper | None = None,
    faults: Sequence[Fault] | None = None,
    cache: EvaluationCache | None = None,
    track: Mapping[str, Any] | None = None,
    goal: Mapping[str, Any] | None = None,
    work: Mapping[str, Any] | None = None,
    t: float | None = None,
    ecu: EcuSummary | None = None,
) -> StateMessage:
    """The message for one cycle. ``status``: the link's :class:`~bridge.link.state.LinkStatus` at
    clock time ``now`` [s]; ``reference``: what is being streamed, or None; ``stale_after_s``: the
    link's measurement age limit [s]; ``feedforward``: the
    :class:`~bridge.link.unit_loop.FeedforwardShaper` (whether it is on, and how many references the
    hard-limit check made it pull back towards the plan); ``faults``: what the motion controller
    holds; ``cache``: keeps the guard's evaluations while their inputs do not change; ``t``: the
    message's wall-clock time [s] (default: now); ``ecu``: its ECU summary when it was taken earlier
    (default: :meth:`EcuSummary.of` now)."""
    t = time.time() if t is None else t
    ls = status.state
    memo = cache if cache is not None else EvaluationCache()
    margin: KinematicMargin | None
    if reference is not None:
        ref = reference
        key: Hashable = ("reference", ref.actuators.tobytes(), ref.rates.tobytes())
        margin = memo.get("margin", key, lambda: _safe(lambda: guard.margin(ref.actuators, ref.rates)))
    elif ls is not None:
        meas = ls
        margin = memo.get(
            "margin",
            ("measured", meas.counts),
            lambda: _safe(lambda: guard.margin(meas.actuators.as_array(), np.zeros(5))),
        )
    else:
        margin = None
    if ls is None:
        stability = None
    else:
        at = ls
        stability = memo.get(
            "stability",
            at.counts,
            lambda: _safe(lambda: StabilityMargins.of(guard.stability_at(at.actuators.as_array(), at.points))),
        )
    return StateMessage(
        t=t,
        clock=now,
        seq=seq,
        mode=mode,
        motion=motion_kind,
        motion_id=motion_id,
        limited=dict(limited),
        measured=ls,
        reference=reference,
        kinematic_margin=margin,
        stability=stability,
        ecu=EcuSummary.of(status, now, stale_after_s, feedforward, faults) if ecu is None else ecu,
        maneuver=maneuver,
        track=track,
        goal=goal,
        work=work,
    )
