"""The motion controller: one motion at a time, streamed to the ECU through the CAN link.

:class:`MotionController` owns the control thread. Every cycle (the control rate, 50 Hz by
default, on absolute deadlines) it reads the link's status, evaluates the active motion at
the current time, converts the pose-space reference to actuators with the exact inverse, shapes
them into the reference under which each cylinder's unit loop follows the motion
(:class:`bridge.link.unit_loop.FeedforwardShaper`; the state's ``reference`` stays the planned one) and
hands that to the link's ``send_reference`` (:class:`~bridge.service.motion.link_port.LinkPort`;
:meth:`bridge.link.can_link.CanLink.send_reference` checks every hard limit and the AD range before
anything reaches the bus); the state snapshot is published first thing in the cycle, so its period
is as regular as the wake-ups.

Motions (each with a ``motion_id``, one at a time):

* **goto / preset / maneuver step** — a guarded plan (:meth:`planner.limits.guard.Guard.plan`).
  A new one replaces the running one smoothly: the new plan starts from the running motion's
  position, velocity and acceleration at a switch time ``_PLAN_LEAD_S`` ahead (planning takes
  5-30 ms), so nothing jumps. If planning took longer than the lead, it is planned again from a
  lead of 1.5 × the time it took; a plan from rest starts whenever it is ready (a resting start
  does not age), unless that start was the measured pose and the pistons moved more than
  5 mm / 5 mrad meanwhile.
* **jog** — pose rates with a time-to-live through :class:`planner.trajectory.JogController`,
  rates re-checked every cycle by :meth:`Guard.check_jog` (stability ahead, end stops) and capped
  at the workspace faces; when the TTL runs out the jog brakes to rest (dead-man).
* **stop** — the jerk-limited shortest stop (:meth:`TrajectoryPlanner.plan_stop`).

Precedence stop > jog > goto/preset/maneuver: a stop aborts anything and new motion is refused
until it has come to rest; a jog aborts a goto or maneuver and takes over from its state; a goto
is refused while a jog command is live (its TTL not expired) and replaces a jog that is braking.

Modes: ``auto`` allows every motion; ``attach`` allows jog only, its rates capped at
``ATTACH_SPEED_SCALE`` of full speed; ``manual`` (per-cylinder in the thesis), ``transport`` and
``config`` refuse motion (stop is always allowed). A mode change while a motion (or a maneuver)
runs is refused with the reason: send stop first — changing modes never stops the hitch by itself.

Faults (``docs/faults.md``): when the link reports a fault or refuses a reference, the motion
is aborted, the reference stream stops (the ECU watchdog zeroes its valves) and nothing moves
until a fresh command — an old plan is never resumed. The controller keeps its own fault record
(:class:`~bridge.service.motion.fault_book.FaultBook` of :class:`~bridge.service.motion.types.Fault`):
``stale_measurement`` and ``ecu_heartbeat``
(:data:`~bridge.service.motion.types.SELF_CLEARING_FAULTS`) clear themselves, with a
``fault_cleared`` event, once the ECU's data has been fresh for
:data:`~bridge.service.motion.types.FAULT_CLEAR_AFTER_S`; every other fault latches until
:meth:`MotionController.ack_faults` (``faults/ack``). While any fault is held, motion is refused
(code ``ecu``, naming it); stop is always accepted. After a motion ends the final reference is
held (streamed) so the ECU keeps the cylinders there.

Deadlines: a goto, preset or maneuver may carry a ``deadline`` (clock time [s]) and the
``issued`` time of its request (``time.monotonic()`` when it arrived). One that cannot start
moving by its deadline, or that arrived before the latest stop, is refused with ``busy``; it is
never run later.

Times: one clock, the link's (``clock()`` [s]). Public methods may be called from any thread: one
lock guards the control state and is only held for O(1) work (no planning, validation, storage
or serialisation under it); goto planning runs outside it on ``plan_guard`` (its own model,
under its own lock, waited for no longer than the request's deadline), and a generation counter
tells whether something else started meanwhile. The plan is handed to the control thread as the
new active motion, which takes over from the running one at its switch time. Events are numbered
(``seq``) under the lock and delivered in that order, and state messages serialised, by the
:class:`~bridge.service.motion.outbox.Outbox` (its own thread once :meth:`MotionController.start`
ran). At rest nothing is recomputed per cycle: the held reference, its inverse and the state
message's guard evaluations are kept while the pose does not change.
The values the controller works with are in :mod:`bridge.service.motion.types`, its running
maneuver in :mod:`bridge.service.maneuvers.slot`, its state message in
:mod:`bridge.service.state_message`.
"""

from __future__ import annotations

import itertools
import math
import secrets
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import numpy as np

from bridge.link.count_tail import CountTail, plan_count_tail
from bridge.link.state import LinkFaultError, LinkStatus, ReferenceRefused
from bridge.link.unit_loop import FeedforwardShaper, build_unit_loops
from bridge.service.gnss import GnssTracker
from bridge.service.maneuvers.language import ValidationResult, guarded_plan_step
from bridge.service.maneuvers.runner import AbortReason, LoopState, ManeuverRunner
from bridge.service.maneuvers.slot import ManeuverSlot
from bridge.service.maneuvers.steps import step_words
from bridge.service.motion.fault_book import FaultBook
from bridge.service.motion.following import FOLLOWING_ERROR, FollowingErrorLimits, FollowingSupervisor
from bridge.service.motion.link_port import LinkPort
from bridge.service.motion.outbox import Outbox
from bridge.service.motion.types import (
    ATTACH_SPEED_SCALE,
    MODES,
    TRACK_FRAMES,
    ActiveMotion,
    Event,
    Fault,
    FaultAck,
    JogAccepted,
    JogMotion,
    MotionAccepted,
    MotionError,
    PlanMotion,
    Reference,
    TrackAccepted,
    TrackMotion,
    check_mode_allows,
    check_precedence,
    implement_selected_event,
    plan_state,
    pose_dict,
    streamed_reference,
    tail_at,
)
from bridge.service.periodic import PeriodicThread
from bridge.service.state_message import (
    EcuSummary,
    EvaluationCache,
    StateMessage,
    build_state_message,
    link_problem,
    plan_goal,
)
from planner.errors import HitchError
from planner.limits.guard import Guard, GuardedPlan
from planner.limits.implement_limits import ImplementLimits, track_bounds
from planner.limits.tractor import ImplementRecord
from planner.model.types import CONTROLLED_POSE_UNITS, KinematicsError
from planner.trajectory import JogController, MotionState, Plan
from planner.trajectory.track import TRACK_DOFS, TrackFollower, TrackInputError, TrackStateError

__all__ = ["LIVE_SESSION", "MotionController", "MotionControllerError", "TrackSensors"]

#: :meth:`MotionController.track_setpoint_refused`'s session for a put whose session is not known (dropped unread)
LIVE_SESSION = "live"

_PLAN_LEAD_S = 0.08  # a replacing plan starts this far ahead of the request (planning time) [s]
_MOVED = 5e-3  # m or rad: a measured start pose that moved more while planning is re-planned
_PLAN_TRIES = 4  # plans made for one goto before it is refused as too busy
#: the motions that end with the profile's count approach: gotos, the positioning requests. Presets (a quick raise,
#: a return to work) and maneuver steps (headland sequences on a field line's timing) do not wait its 1.2 s; a stop
#: and a jog's braking only brake
_COUNT_APPROACH_KINDS = frozenset({"goto"})


#: how many ended track sessions the controller remembers the reason of (MotionController._not_live)
ENDED_TRACKS_KEPT = 16


@dataclass
class _StoppedJog:
    """A jog a stop ended while its command was live: its ``holder``, the clock time [s] ``until`` which their jogs
    are refused (extended by each refused command's ttl) and the stop's ``stop_id``."""

    holder: str | None
    until: float
    stop_id: int


class MotionControllerError(HitchError, RuntimeError):
    """The controller used out of order (started twice)."""


class TrackSensors(Protocol):
    """The tractor's sensors a track session's frames need (fresh readings only, else None)."""

    def attitude(self, now: float) -> tuple[float, float] | None:
        """Tractor body roll and pitch relative to gravity [rad] (slope sensor; SAE J670 signs:
        roll positive right side down, pitch positive nose up)."""
        ...

    def ground_distance(self, now: float) -> float | None:
        """Height of the implement's reference point above the ground below it [m]."""
        ...

    # optional: ``attitude_rate(now) -> (roll rate, pitch rate) | None`` [rad/s] and
    # ``ground_distance_rate(now) -> float | None`` [m/s] (the frame's own motion, added to setpoint velocities)


#: a rejected setpoint is announced at most this often per session [s] (each one is counted)
_REJECTION_EVENT_EVERY_S = 1.0
#: a motion request that arrived within this time after a stop is refused too [s]: it may have been sent before
#: the stop and stamped late (a request's arrival is stamped when the service's Zenoh callback runs, which a
#: loaded service runs tens of ms late, while the stop goes to the core on its own path; a safety trial under a
#: request flood: 14 of 15 gotos sent 0.2-9 ms before a stop started after it, 2 of 8 at 25 ms)
STOP_GRACE_S = 0.1
#: track session ids start at a random number below this (and stay below 2^53, JSON's exact integers)
SESSION_ID_SPAN = 2**40


def first_session_id() -> int:
    """The first track session id of a controller: random in [1, :data:`SESSION_ID_SPAN`], so two runs of the
    service (or two services) practically never hand out the same id."""
    return secrets.randbelow(SESSION_ID_SPAN) + 1


class MotionController:
    """See the module docstring.

    Args:
        guard: guard (and its planner/model) used by the control thread only.
        plan_guard: a second guard on its own model for planning requests (models are not
            thread-safe: their CasADi buffers are shared).
        link: the CAN link (:class:`~bridge.service.motion.link_port.LinkPort`, e.g. a
            :class:`bridge.link.can_link.CanLink`).
        clock: the link's clock [s].
        on_state / on_event: called with JSON-ready dicts (state every ``state_every`` cycles),
            in order, from the outbox (its own thread once started; else the calling thread).
        odometer: cumulative distance travelled by the tractor [m] or None (maneuver ``wait_for``).
        spawn: runs the planning of a maneuver step off the control thread (default: a new thread;
            tests pass ``lambda fn: fn()`` for deterministic runs).
        sensors: the tractor's slope and ground-distance readings (:class:`TrackSensors`) for track
            sessions in the ``level`` and ``ground`` frames (None: only the ``tractor`` frame).
    """

    def __init__(
        self,
        guard: Guard,
        plan_guard: Guard,
        link: LinkPort,
        clock: Callable[[], float],
        *,
        on_state: Callable[[dict[str, Any]], None] | None = None,
        on_event: Callable[[Event], None] | None = None,
        state_every: int = 1,
        odometer: Callable[[], float | None] | None = None,
        mode: str = "auto",
        spawn: Callable[[Callable[[], None]], None] | None = None,
        feedforward: bool = True,
        sensors: TrackSensors | None = None,
        following: FollowingErrorLimits | None = None,
    ):
        self.guard, self.plan_guard = guard, plan_guard
        self.planner = guard.planner
        self.link = link
        self.shaper = FeedforwardShaper(
            build_unit_loops(self.planner.model.profile),
            self.planner.inverse.solve_full,
            link.check_reference,
            enabled=feedforward,
        )
        self.clock = clock
        self.dt = 1.0 / self.planner.rate
        self.outbox = Outbox(on_event or (lambda e: None), on_state or (lambda s: None))
        self._odometer: Callable[[], float | None] = odometer or (lambda: None)
        self._spawn: Callable[[Callable[[], None]], None] = spawn or (
            lambda fn: threading.Thread(target=fn, name="hitch-maneuver-plan", daemon=True).start()
        )
        self._plan_step = guarded_plan_step(plan_guard)
        self.state_every = max(1, int(state_every))
        self.state_wanted: Callable[[], bool] = lambda: True
        """Whether anyone listens to the state now (the core process: a Zenoh matching listener on its
        state publisher); a cycle builds no state nobody receives — at rest with no viewer the state
        costs nothing."""
        self._lock = threading.RLock()
        self._plan_lock = threading.Lock()
        self._ids = itertools.count(1)
        self._mode = mode if mode in MODES else "auto"
        self._active: ActiveMotion | None = None
        self._hold: MotionState | None = None
        self._hold_ref: Reference | None = None  # the held reference, computed once per hold
        self._hold_actuators: np.ndarray | None = None  # a count approach's final references, held (SI)
        self._last_id: int | None = None
        self._generation = 0
        self.gnss = GnssTracker(clock)  # the tractor's GNSS position and the field's lines (wait_for line)
        self._maneuver = ManeuverSlot(self.gnss)
        #: what the controller holds, and the policy raising and clearing it (docs/faults.md)
        self._faults = FaultBook(link.config.stale_after_s)
        self._stopped_at = -math.inf  # time.monotonic() of the latest stop
        #: a jog a stop ended while its command was live: that holder's jogs are refused while their stream goes on
        #: (each extends it by its ttl): a held button must be released and pressed again after a stop (a review:
        #: alice's held page restarted the hitch 0.45 s after bob's stop, and bob, told "or stop", never got the jog)
        self._stopped_jog: _StoppedJog | None = None
        self._resume_deadline: float | None = None  # a maneuver resume's or skip's deadline for its next step
        self._limited: dict[str, str] = {}
        self._reference: Reference | None = None
        #: the cylinders follow the streamed references (fault following_error; bridge.service.motion.following)
        self.following = FollowingSupervisor(following)
        self._eval_cache = EvaluationCache()
        self._seq = 0
        self._cycle_n = 0
        self._thread: PeriodicThread | None = None
        self.sensors = sensors
        # track session ids from a random start: a streamer of an earlier run of the service (its ids began at 1
        # too) must never feed a session of this one (a new user's report: after a restart an old streamer's
        # puts for session 1 drove a new client's session 1 135 mm away)
        self._sessions = itertools.count(first_session_id())
        #: how the last few track sessions ended (session → reason): a setpoint or stop for one says why
        self._ended_tracks: dict[int, str] = {}
        self._rejection_event_at = -math.inf
        #: work control of track sessions (bridge.service.work.WorkControl; set by machine.build_controller)
        self.work: Any = None
        self._goal_plan: Any = None  # the plan whose end pose ``_goal`` holds (state message)
        self._goal: dict[str, Any] | None = None

    # ------------------------------------------------------------------ life cycle
    def start(self) -> MotionController:
        """Start the outbox thread and the control thread."""
        if self._thread is not None:
            raise MotionControllerError("motion controller already started")
        self.outbox.start()
        self._thread = PeriodicThread(self.dt, self.cycle, name="hitch-control", on_error=self._on_cycle_error).start()
        return self

    @property
    def thread(self) -> PeriodicThread | None:
        """The control thread (None before :meth:`start`)."""
        return self._thread

    @property
    def overruns(self) -> int:
        """Control cycles that started late (since start)."""
        return 0 if self._thread is None else self._thread.overruns

    def close(self, brake_s: float = 0.4, why: str = "service shutting down") -> None:
        """Stop any motion, end the control thread and the reference stream; ``why`` is the motion's abort reason.

        A moving hitch gets the jerk-limited stop for up to ``brake_s`` seconds; then the stream
        ends and the ECU watchdog zeroes the valves (within its 100 ms) whatever is left.
        """
        if self._thread is not None and self._thread.alive and self._active is not None:
            try:
                self.stop(why)
            except ValueError:
                pass
            deadline = time.monotonic() + brake_s
            while self._active is not None and time.monotonic() < deadline:
                time.sleep(self.dt / 2)
        events: list[Event] = []
        with self._lock:
            self._abort_all(why, self.clock(), events, "stop")
            self._post(events)
        if self._thread is not None:
            self._thread.stop(0.5)
        self.link.stop_motion()
        self.outbox.stop(0.5)

    # ------------------------------------------------------------------ queries
    @property
    def mode(self) -> str:
        return self._mode

    @property
    def faults(self) -> tuple[Fault, ...]:
        """The faults the controller holds now (oldest first)."""
        with self._lock:
            return self._faults.held

    def current_state(self) -> MotionState:
        """The commanded pose-space state now (or the measured pose at rest when idle)."""
        with self._lock:
            return self._predict(self.clock())

    def set_mode(self, mode: str) -> str:
        if mode not in MODES:
            raise MotionError("bad_request", f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        with self._lock:
            if mode != self._mode and (self._active is not None or self._maneuver.running):
                a = self._active
                braking = a is not None and getattr(a, "kind", None) == "stop" and not self._maneuver.running
                if a is None:  # a maneuver paused at rest or between steps: not "moving" (a new user's report)
                    raise MotionError(
                        "busy",
                        f"mode change to {mode!r} refused while maneuver {self._maneuver.name or self._maneuver.id} "
                        "runs (paused or not); send stop first",
                    )
                what = f"motion {a.motion_id}"
                todo = "wait until it is at rest" if braking else "send stop first and wait until it is at rest"
                if isinstance(a, TrackMotion):  # levelling on at rest is not "moving" (an operator's trial)
                    raise MotionError(
                        "busy",
                        f"mode change to {mode!r} refused while track session {a.session} ({a.frame} frame) follows "
                        f"its setpoints (motion {a.motion_id}): end it first (track/stop: the terminal's levelling "
                        "off, hitch track's Ctrl-C) or send stop",
                    )
                raise MotionError(
                    "busy",
                    f"mode change to {mode!r} refused while the hitch is "
                    f"{'braking to rest' if braking else 'moving'} ({what}); {todo}",
                )
            if mode != self._mode:
                old, self._mode = self._mode, mode
                self._post([{"event": "mode_changed", "mode": mode, "previous": old}])
        self.outbox.flush()
        return mode

    def preview(self, goal: Mapping[str, float], speed_scale: float = 1.0) -> GuardedPlan:
        """The guarded plan a goto would run now (no motion); raises PlanError / GuardRefusal."""
        return self.preview_from(self.preview_start(), goal, speed_scale)

    def preview_start(self) -> MotionState:
        """The state a goto sent now would start from (O(1); the neutral pose before any measurement)."""
        with self._lock:
            return self._predict(self.clock() + _PLAN_LEAD_S, require_link=False)

    def preview_from(self, start: MotionState, goal: Mapping[str, float], speed_scale: float = 1.0) -> GuardedPlan:
        """The guarded plan from ``start`` on the planning guard (under its lock; no motion)."""
        with self._plan_lock:
            return self.plan_guard.plan(start, goal, speed_scale=speed_scale)

    def preview_with_tail(
        self, start: MotionState, goal: Mapping[str, float], speed_scale: float = 1.0
    ) -> tuple[GuardedPlan, CountTail | None]:
        """:meth:`preview_from` and the count approach a goto of that plan would end with, under one hold of the
        planning lock (the same implement and limits for both)."""
        with self._plan_lock:
            gp = self.plan_guard.plan(start, goal, speed_scale=speed_scale)
            return gp, self._count_tail(gp.plan)

    def plan_step(self, start: MotionState, goal: Mapping[str, float], speed_scale: float) -> tuple[float, MotionState]:
        """Guarded planning on the planning guard (for maneuver validation): (duration [s], end state)."""
        with self._plan_lock:
            return self._plan_step(start, goal, speed_scale)

    # ------------------------------------------------------------------ commands
    def goto(
        self,
        goal: Mapping[str, float],
        speed_scale: float = 1.0,
        *,
        kind: str = "goto",
        label: str | None = None,
        deadline: float | None = None,
        issued: float | None = None,
    ) -> MotionAccepted:
        """Plan and start a move to a (partial) goal; replaces a running goto/preset/maneuver.

        ``deadline``: clock time [s] by which it must start moving, else ``busy`` (None: no limit);
        ``issued``: ``time.monotonic()`` when its request arrived (a stop after that cancels it).
        """
        return self._start_plan(goal, speed_scale, kind, label, runner=None, deadline=deadline, issued=issued)

    def jog(
        self,
        rates: Mapping[str, float],
        ttl_s: float,
        *,
        deadline: float | None = None,
        issued: float | None = None,
        holder: str | None = None,
    ) -> JogAccepted:
        """Start or refresh a jog (pose rates, m/s and rad/s) for ``ttl_s`` seconds. ``deadline`` and
        ``issued`` as for :meth:`goto`: a jog that waited past its deadline, or that arrived before the
        latest stop, is refused (``busy``), never run later.

        ``holder``: who sends it (the request's user; None: an anonymous client). One jog at a time: while the
        live jog's command has not expired, a jog of another holder is refused (``busy``, naming the holder and
        the time left) — two operators' pages held z+ and z− alternately and both were taken, the hitch went down
        66.7 mm while one held "up" (a terminal trial). Once the command expired (released) another may take the
        jog over. Anonymous clients cannot be told apart: their jogs are one jog, as before."""
        v = np.array([float(rates.get(k, 0.0)) for k in ("vx", "vz", "vroll", "vpitch")])
        with self._lock:
            self._check_stopped_jog(holder, ttl_s)
            self._check_allowed("jog")
            self._check_no_fault("jog")
            self._check_controllers_on("jog")
            self._check_late("jog", self.clock(), deadline, issued)
            capped: dict[str, str] = {}  # what the mode caps, said in the reply like any other limit
            if self._mode == "attach":  # slow rates, same responsiveness (acceleration and jerk not scaled)
                cap = ATTACH_SPEED_SCALE * self.planner.any_direction.velocity
                for k, vk, ck in zip(("x", "z", "roll", "pitch"), v, cap, strict=True):
                    if abs(vk) > ck:
                        capped[f"{k}{'+' if vk > 0 else '-'}"] = "mode:attach"
                v = np.clip(v, -cap, cap)
            now = self.clock()
            m = self._active
            if isinstance(m, PlanMotion) and m.kind == "stop":
                raise MotionError(
                    "busy", f"a stop is in progress (motion {m.motion_id}); jog is refused until the hitch is at rest"
                )
            events: list[Event] = []
            if isinstance(m, JogMotion) and m.holder != holder and now < m.expires:
                who = "an anonymous client" if m.holder is None else f"user {m.holder!r}"
                raise MotionError(
                    "busy",
                    f"a jog of {who} is live (motion {m.motion_id}, {m.expires - now:.2f} s left): one jog at a time; "
                    "it is yours once they release it (its ttl) — or stop",
                )
            if not isinstance(m, JogMotion):
                start = self._predict(now)
                if m is not None:
                    events.append(self._ev("motion_aborted", m, reason="replaced by jog"))
                self._maneuver.abort(now, "interrupted", "a jog took over", events)
                jc = JogController(self.planner, start)
                m = JogMotion(next(self._ids), jc, v, now + ttl_s, t_state=now)
                self._install(m)
                events.append(self._ev("motion_started", m, kind="jog"))
            m.holder, m.caps = holder, capped
            acc = m.refresh(self.guard, v, now + ttl_s)
            self._post(events)
        self.outbox.flush()
        return acc

    def _check_stopped_jog(self, holder: str | None, ttl_s: float) -> None:
        """Refuse (``busy``) a jog of the holder whose live jog a stop ended while their commands keep coming:
        a held button (a page sends every 80 ms) goes on after another operator's stop and restarted the hitch
        once the stop had braked. Each refused command extends the latch by its ttl; released (no command of
        theirs within it), they may jog again. Another holder is not held back by it."""
        sj = self._stopped_jog
        if sj is None:
            return
        now = self.clock()
        if now >= sj.until:
            self._stopped_jog = None
            return
        if sj.holder != holder:
            return
        sj.until = max(sj.until, now + float(ttl_s))
        raise MotionError(
            "busy",
            f"jog ended by a stop (motion {sj.stop_id}) while it was held: release the jog for at least {ttl_s:.2f} s "
            "(its ttl), then press again",
        )

    def stop(self, reason: str = "stop requested") -> int | None:
        """Abort anything; brake jerk-limited to rest. Returns the stop motion's id (None when at rest).
        ``reason``: what the abort events say (an operator's stop, the router lost …).

        Every motion request that arrived before it and has not started yet is cancelled.
        """
        return self.stop_report(reason)["motion_id"]

    def stop_report(self, reason: str = "stop requested") -> dict[str, Any]:
        """:meth:`stop`, with what it ended: ``{"motion_id": the stop's id (None: at rest), "ended": [what the
        stop aborted besides the motion, in words: "maneuver 'mw' at step 1 (index 0)"]}``. A maneuver waiting
        between its motions has no motion to brake: the stop that ended it answered only "at rest" (an operator's
        trial)."""
        events: list[Event] = []
        with self._lock:
            self._stopped_at = time.monotonic()
            now = self.clock()
            m = self._active
            if isinstance(m, JogMotion) and now < m.expires:  # a held jog: released before it may go on
                self._stopped_jog = _StoppedJog(m.holder, m.expires, m.motion_id)
            self._maneuver.abort(now, "stop", reason, events)
            mid = self._brake(now, reason, events)
            ended = [
                f"maneuver {_maneuver_words(e)}" + ("" if e.get("step") is None else f" at {step_words(e['step'])}")
                for e in events
                if e.get("event") == "maneuver_aborted"
            ]
            self._post(events)
        self.outbox.flush()
        return {"motion_id": mid, "ended": ended}

    # ------------------------------------------------------------------ track mode
    def track_start(
        self,
        frame: str,
        dofs: tuple[str, ...] | list[str],
        ttl_s: float,
        *,
        deadline: float | None = None,
        issued: float | None = None,
        replace: bool | int = False,
        caller: str = "track/start",
    ) -> TrackAccepted:
        """Start a track session (``docs/tracking.md``): setpoints of ``dofs`` in ``frame`` follow with
        online jerk-limited motion; without a setpoint within ``ttl_s`` the hitch brakes to rest and
        the session ends. Takes over a running goto or maneuver (aborted) from its state; refused
        while a stop brakes or a jog command is live (stop > jog > track > goto). Another live session
        whose stream is fresh (not ending) is taken over only with ``replace`` True, or ``replace`` its
        session number (work control restarting its own); else ``busy``: two streams would fight over
        the hitch, each cutting the other off. ``caller``: the request the refusal advises for (``work/start`` has
        no ``replace``). ``deadline`` and ``issued`` as for :meth:`goto`."""
        if frame not in TRACK_FRAMES:
            raise MotionError("bad_request", f"frame must be one of {', '.join(TRACK_FRAMES)}, got {frame!r}")
        with self._lock:
            self._check_allowed("track")
            self._check_no_fault("track")
            self._check_controllers_on("track")
            now = self.clock()
            self._check_late("track", now, deadline, issued)
            m = self._active
            if isinstance(m, PlanMotion) and m.kind == "stop":
                raise MotionError("busy", f"a stop is in progress (motion {m.motion_id}); track is refused until rest")
            if isinstance(m, JogMotion) and now < m.expires:
                raise MotionError(
                    "busy", f"a jog command is live (motion {m.motion_id}); jog has precedence over track"
                )
            if isinstance(m, TrackMotion) and not m.ending and replace is not True and replace != m.session:
                owned = self.work is not None and self.work.owns(m.session)
                whose = " (work control's: work/stop ends it)" if owned else ""
                how = (
                    "track/stop ends it; track/start with replace: true (hitch track --replace) takes it over"
                    if caller == "track/start"
                    else "end it first (track/stop: hitch track's Ctrl-C, the terminal's levelling off)"
                )
                live = f"track session {m.session} (frame {m.frame}, dof {', '.join(m.dofs)}) is live{whose}"
                raise MotionError("busy", f"{live}: {how}")
            why = link_problem(self.link.status(now), now, self.link.config.stale_after_s)
            if why:
                raise MotionError("ecu", f"track refused: {why}")
            self._frame_readings(frame, now, "track refused")  # the frame's sensor must be there now
            start = self._predict(now)
            try:
                bounds = track_bounds(self.guard.implement_limits)  # the implement's (docs/implements.md)
                follower = TrackFollower(self.planner, start, dofs, ttl_s, t0_s=now, bounds=bounds)
            except TrackInputError as exc:
                raise MotionError("bad_request", str(exc)) from None
            events: list[Event] = []
            if m is not None:
                events.append(self._ev("motion_aborted", m, reason="replaced by track"))
            self._maneuver.abort(now, "interrupted", "a track session took over", events)
            tm = TrackMotion(next(self._ids), next(self._sessions), follower, frame, t_state=now)
            self._install(tm)
            events.append(
                self._ev("motion_started", tm, kind="track", session=tm.session, frame=frame, dof=list(tm.dofs))
            )
            self._post(events)
        self.outbox.flush()
        return TrackAccepted(tm.session, tm.motion_id, frame, tm.dofs, float(ttl_s))

    def track_setpoint(
        self,
        session: int,
        seq: int,
        pose: Mapping[str, float],
        velocity: Mapping[str, float] | None = None,
        *,
        acceleration: Mapping[str, float] | None = None,
        jerk: Mapping[str, float] | None = None,
    ) -> dict[str, Any]:
        """One streamed setpoint (O(1)): ``pose`` [m, rad] of the session's DOFs in its frame,
        optionally their ``velocity`` [m/s, rad/s] and, in frame ``tractor`` only, ``acceleration``
        [m/s², rad/s²] and ``jerk`` [m/s³, rad/s³] (a client streaming a path sends its derivatives:
        the follower then meets the path exactly, :meth:`TrackFollower.set_setpoint`). Returns
        ``{"accepted", "limited", …}``; an old or out-of-order ``seq`` is ignored (counted). Raises
        :class:`MotionError` for a session that is not the live one or a setpoint that cannot be taken
        (the reason names the field / sensor)."""
        with self._lock:
            m = self._active
            if not isinstance(m, TrackMotion) or m.session != session:
                raise MotionError("not_found", self._not_live(session, m))
            if self.work is not None and self.work.owns(session):  # work control alone feeds a work session
                self.work.refuse_setpoint(m)  # counted; raises MotionError busy (bridge.service.work)
            now = self.clock()
            try:
                # the body is checked before its seq: a field error is said whatever the seq, and a refused
                # setpoint leaves its seq for the corrected resend (it used it up: a new user's report)
                new = m.seq.is_new(seq, now)
                target = self._to_tractor_frame(m, pose, now)
                if (acceleration is not None or jerk is not None) and m.frame != "tractor":
                    raise MotionError(
                        "bad_request",
                        f"setpoint.acceleration / jerk: only in frame tractor (session frame {m.frame})",
                    )
                self._check_plausible_in_frame(m, pose, target)
                v_tractor = self._frame_velocity(m, pose, velocity, now)
                if not new:
                    m.follower.validate(target, v_tractor)
                    m.seq.accept(seq, now)  # counted as ignored
                    self._announce_ignored(m, seq, now)
                    return {"accepted": False, "ignored": "seq", "session": session, "seq": seq}
                sp = m.follower.set_setpoint(target, v_tractor, now, acceleration=acceleration, jerk=jerk)
                m.seq.accept(seq, now)
            except (TrackInputError, TrackStateError, MotionError) as exc:
                text = str(exc).removeprefix("track/setpoint: ")
                if isinstance(exc, TrackStateError) and m.follower.stale:  # no resume() in the service
                    text = (
                        f"track session {m.session}: the setpoint stream went stale (no setpoint within "
                        f"{m.follower.ttl_s:g} s) and the hitch brakes to rest; the session takes no more "
                        "setpoints: track/start starts a new one"
                    )
                self._count_rejection(m, text, now)
                code = exc.code if isinstance(exc, MotionError) else "bad_request"
                raise MotionError(code, text) from None
            finally:
                m.take_stop(seq)
            m.accepted += 1
        self.outbox.flush()
        return {"accepted": True, "session": session, "seq": seq, "limited": dict(sp.limited)}

    def track_setpoint_refused(self, session: object, message: str) -> None:
        """A setpoint for ``session`` that was refused before it reached the session (its request did not
        parse: a value outside the schema's range, a wrong type): counted and announced as a rejection
        of the live session, as :meth:`track_setpoint` does with the setpoints it cannot take. Nothing
        else changes; another session's (or none's) is left alone. ``session`` :data:`LIVE_SESSION`: whichever is
        live (a put dropped unread, whose session is not known)."""
        with self._lock:
            m = self._active
            if not isinstance(m, TrackMotion) or isinstance(session, bool):
                return
            if session != LIVE_SESSION and m.session != session:
                return
            self._count_rejection(m, message, self.clock())
        self.outbox.flush()

    def _announce_ignored(self, m: TrackMotion, seq: int, now: float) -> None:
        """Announce setpoints ignored for their ``seq``, at most one ``track_setpoint_ignored`` event per
        ``_REJECTION_EVENT_EVERY_S`` (call under the lock): a second sender putting a larger ``seq`` into a live
        session had the session's own stream ignored until it went stale, and nothing said so (a fleet trial)."""
        if now - m.ignored_announced_s < _REJECTION_EVENT_EVERY_S:
            return
        m.ignored_announced_s = now
        self._post(
            [
                {
                    "event": "track_setpoint_ignored",
                    "motion_id": m.motion_id,
                    "session": m.session,
                    "ignored": m.seq.ignored,
                    "message": (
                        f"seq {seq} is not above the last one session {m.session} took ({m.seq.last}): ignored — a "
                        "late or repeated setpoint, or another client sending into this session"
                    ),
                }
            ]
        )

    def _count_rejection(self, m: TrackMotion, message: str, now: float) -> None:
        """Count a rejected setpoint of ``m`` (the state's ``track`` entry) and announce it, at most one
        ``track_setpoint_rejected`` event per ``_REJECTION_EVENT_EVERY_S`` (call under the lock)."""
        m.rejected += 1
        m.last_rejection = message
        if now - self._rejection_event_at >= _REJECTION_EVENT_EVERY_S:
            self._rejection_event_at = now
            self._post(
                [
                    {
                        "event": "track_setpoint_rejected",
                        "motion_id": m.motion_id,
                        "session": m.session,
                        "rejected": m.rejected,
                        "message": message,
                    }
                ]
            )

    def track_stop(self, session: int | None = None, last_seq: int | None = None) -> dict[str, Any]:
        """End the live track session smoothly (the shortest jerk-limited stop); ``session`` None: whichever
        is live. ``last_seq``: the last setpoint the client sent — the follower takes it before it brakes
        (it may arrive after the stop; a lost one is waited for at most the session's time-to-live)."""
        with self._lock:
            m = self._active
            if not isinstance(m, TrackMotion) or (session is not None and m.session != session):
                if session is None:  # any live session was meant: there is none
                    raise MotionError("not_found", "no track session is live (track/start starts one)")
                raise MotionError("not_found", self._not_live(session, m))
            if m.reason is None:
                m.reason = "track/stop"
            if self.work is not None and self.work.owns(m.session):
                last_seq = None  # work control feeds it (no client sequence to wait for): brake now
            now_braking = m.stop_after_seq(last_seq, self.clock())
            reply: dict[str, Any] = {"stopping": True, "session": m.session, "motion_id": m.motion_id}
            if not now_braking:
                reply["after_seq"] = last_seq
            return reply

    def _frame_velocity(
        self, m: TrackMotion, pose: Mapping[str, float], velocity: Mapping[str, float] | None, now: float
    ) -> Mapping[str, float] | None:
        """A setpoint's velocity in the tractor frame: the frame's own motion added (``docs/tracking.md``):
        ``level``: + the tractor's roll and pitch rates; ``ground``: + the rate of the ground height under
        the implement (ż_ref − ḋ, the hitch's commanded rate less the ground distance's). Sensors without
        rates (or a frame without motion): the velocity as given."""
        if m.frame == "tractor" or self.sensors is None:
            return velocity
        out = dict(velocity or {})
        if m.frame == "level":
            rate_of = getattr(self.sensors, "attitude_rate", None)
            rates = None if rate_of is None else rate_of(now)
            if rates is None:
                return velocity
            for k, r in zip(("roll", "pitch"), rates, strict=True):
                if k in pose:
                    out[k] = float(out.get(k, 0.0)) + float(r)
            return out
        rate_of = getattr(self.sensors, "ground_distance_rate", None)
        d_rate = None if rate_of is None else rate_of(now)
        if d_rate is None or "z" not in pose:
            return velocity
        z_rate = float(m.follower.state.velocity[1])
        out["z"] = float(out.get("z", 0.0)) + z_rate - float(d_rate)
        return out

    def _frame_readings(self, frame: str, now: float, what: str) -> tuple[tuple[float, float] | None, float | None]:
        """The sensor readings ``frame`` needs now: (attitude, ground distance); MotionError when missing."""
        if frame == "tractor":
            return None, None
        sensors = self.sensors
        if frame == "level":
            att = None if sensors is None else sensors.attitude(now)
            if att is None:
                raise MotionError(
                    "unavailable", f"{what}: frame 'level' needs the tractor's slope sensor (no fresh reading)"
                )
            return att, None
        dist = None if sensors is None else sensors.ground_distance(now)
        if dist is None:
            raise MotionError(
                "unavailable", f"{what}: frame 'ground' needs the implement's ground-distance sensor (no fresh reading)"
            )
        return None, dist

    @staticmethod
    def _check_plausible_in_frame(m: TrackMotion, pose: Mapping[str, float], target: Mapping[str, float]) -> None:
        """A setpoint of a ``level`` or ``ground`` session whose tractor-frame value is not plausible, refused
        naming the value sent and the range in the session's frame (the follower's check names the converted
        value: "z = 0.999268 m" for a ground height of 1.5 m, a new user's report)."""
        if m.frame == "tractor":
            return
        for k, sent in pose.items():
            if k not in TRACK_DOFS or isinstance(sent, bool) or not isinstance(sent, (int, float)):
                continue  # the follower names it
            lo, hi = m.follower.plausible_range(k)
            value = float(target[k])
            if not lo <= value <= hi:
                shift = value - float(sent)
                u = CONTROLLED_POSE_UNITS[k]
                raise MotionError(
                    "bad_request",
                    f"setpoint.pose.{k} = {float(sent):g} {u} in frame {m.frame} ({value:.6g} {u} in the tractor "
                    f"frame) is not a plausible SI value: allowed [{lo - shift:.3f}, {hi - shift:.3f}] {u} in frame "
                    f"{m.frame} now (beyond the workspace it is clipped)",
                )

    def _to_tractor_frame(self, m: TrackMotion, pose: Mapping[str, float], now: float) -> dict[str, float]:
        """A setpoint in the session's frame as a tractor-frame pose (``docs/tracking.md``):

        * ``level``: roll and pitch relative to gravity. The slope sensor's roll φ (right side down)
          lowers the hitch's right side, its pitch θ (nose up) tilts the mast rearward, so
          roll_tractor = roll_level + φ, pitch_tractor = pitch_level + θ;
        * ``ground``: z as the height above the ground under the implement: with the measured hitch
          height z_m and the ground distance d read at it, z_tractor = z_m + (z_ground − d).
        """
        out = dict(pose)
        if m.frame == "tractor":
            return out
        att, dist = self._frame_readings(m.frame, now, "setpoint refused")
        if att is not None:
            roll, pitch = att
            if "roll" in out:
                out["roll"] = float(out["roll"]) + roll
            if "pitch" in out:
                out["pitch"] = float(out["pitch"]) + pitch
        if dist is not None and "z" in out:
            ls = self.link.latest_state()
            if ls is None:
                raise MotionError("unavailable", "setpoint refused: no measured hitch height yet (frame 'ground')")
            z_m = float(ls.pose.controlled()[1])
            stuck = m.ground_watch.check(dist, z_m, now, float(out["z"]) - dist)
            if stuck is not None:  # refused like a missing reading: the session brakes at its ttl
                raise MotionError("unavailable", f"setpoint refused: {stuck}")
            out["z"] = z_m + (float(out["z"]) - dist)
        return out

    def run_maneuver(
        self,
        validated: ValidationResult,
        name: str | None,
        *,
        deadline: float | None = None,
        issued: float | None = None,
    ) -> int:
        """Start a validated maneuver (replaces a running goto/maneuver). Returns its id.

        ``deadline`` and ``issued`` as for :meth:`goto`."""
        with self._lock:
            self._check_startable("maneuver", self.clock(), deadline, issued)
            events: list[Event] = []
            self._maneuver.abort(self.clock(), "interrupted", "replaced by another maneuver", events)
            mid = next(self._ids)
            self._maneuver.start(validated, name, mid)
            self._generation += 1
            self._post(events)
        self.outbox.flush()
        return mid

    def maneuver_control(
        self, action: str, *, deadline: float | None = None, issued: float | None = None
    ) -> dict[str, Any]:
        """``pause``, ``resume`` or ``skip`` the running maneuver (``docs/maneuvers.md``): pause brakes
        the hitch to rest and holds; resume plans the current step again from the pose now; skip ends
        the current step (a motion step brakes) and goes on with the next. ``deadline`` and ``issued``
        as for :meth:`goto` (resume and skip start motion; a pause only brakes and is never refused late)."""
        if action not in ("pause", "resume", "skip"):
            raise MotionError("bad_request", f"action must be one of pause, resume, skip, got {action!r}")
        events: list[Event] = []
        with self._lock:
            now = self.clock()
            if action != "pause":
                self._check_late(f"maneuver {action}", now, deadline, issued)
            if not self._maneuver.running:
                raise MotionError("not_found", "no maneuver is running")  # the API prefixes the key
            try:
                brake = self._maneuver.control(action, now, events)
            except ValueError as exc:  # ManeuverRunError: paused already, not paused, no step left
                raise MotionError("busy", str(exc).removeprefix(f"{action}: ")) from None  # the API prefixes the key
            # a resume's or skip's motion must start by its deadline too: the next cycle plans it (else the
            # maneuver aborts); a refused one leaves nothing behind, and the cycle after drops it (_drive_maneuver)
            self._resume_deadline = None if action == "pause" else deadline
            if brake:
                self._brake(now, f"maneuver {action}", events)
            progress = self._maneuver.progress()
            self._post(events)
        self.outbox.flush()
        return {
            "action": action,
            "maneuver_id": self._maneuver.id,
            "maneuver": None if progress is None else progress.to_json(),
        }

    def distance_travelled(self) -> float | None:
        """The tractor's travelled distance [m] (the odometer; None: none, or silent)."""
        return self._odometer()

    def lines_request(self, op: str, name: str | None = None, geojson: Any = None) -> dict[str, Any]:
        """The field's lines (:mod:`bridge.service.gnss`): ``save`` (GeoJSON), ``list``, ``delete``."""
        if op == "save":
            return {"saved": self.gnss.save_lines(geojson, name)}
        if op == "delete":
            if name is None or not self.gnss.delete_line(name):
                raise MotionError("not_found", f"lines/delete: no line {name!r}")
            return {"deleted": name}
        return {"lines": self.gnss.lines(), "position": self.gnss.position(), "gnss": self.gnss.counts()}

    def post_event(self, event: Event) -> None:
        """Announce ``event`` (numbered in order with the controller's own; any thread, O(1))."""
        with self._lock:
            self._post([dict(event)])
        self.outbox.flush()

    def select_implement(
        self, implement: ImplementRecord | None, limits: ImplementLimits, *, announce: bool = True
    ) -> dict[str, Any]:
        """Give both guards an implement (stability: its mass and CoM) and its limits (``docs/implements.md``);
        refused (``busy``) while a motion or a maneuver runs: send stop first. ``announce=False``: no
        ``implement_selected`` event; the caller posts it (:func:`implement_selected_event`) once everything the
        change touches is recorded (the implement service: its selection, store and presets)."""
        if not self._plan_lock.acquire(timeout=2.0):  # no plan is being made with the old implement
            raise MotionError("busy", "implement change refused: the planner stayed busy; send it again")
        try:
            with self._lock:
                if self._active is not None:
                    raise MotionError(
                        "busy", "implement change refused while the hitch is moving; send stop first and wait for rest"
                    )
                if self._maneuver.running:  # paused at rest, or between steps: said so (it said "moving")
                    raise MotionError(
                        "busy",
                        f"implement change refused while maneuver {self._maneuver.name or self._maneuver.id} runs "
                        "(paused or not); send stop first",
                    )
                for g in (self.guard, self.plan_guard):
                    g.set_implement(implement)
                    g.set_implement_limits(limits)
                self._eval_cache = EvaluationCache()
                self._generation += 1  # a goto planned meanwhile is planned again
                name = None if implement is None else implement.name
                if announce:
                    self._post([implement_selected_event(implement, limits)])
        finally:
            self._plan_lock.release()
        self.outbox.flush()
        return {"implement": name, **limits.to_json()}

    def ack_faults(self) -> FaultAck:
        """Acknowledge the latched faults (``faults/ack``): they are cleared, with a
        ``fault_cleared`` event; self-clearing faults whose data is not fresh yet stay, and so do latched ones
        whose cause the link still sees (``LinkStatus.fault_causes``: our address held or used by another
        node). Motion needs a new command afterwards (nothing resumes)."""
        with self._lock:
            # a latched fault whose cause is still there (another node holds our address, or uses it) is not
            # cleared: after an ack of address_lost the service said "no fault held" and refused every goto
            # "not claimed" (a safety trial); its reason says what holds it
            acked = self._faults.acknowledge(self.link.status(self.clock()))
            if acked:
                # the link's latched flags of these go too (nothing starts): one raised again after this ack
                # is new to the link and reported as a fault; kept latched there until the next accepted
                # reference, a second ECU restart after an ack went unreported and a goto was accepted
                self.link.clear_faults(self.clock(), acked)
                self._post([self._faults.cleared_event(acked)])
            remaining = tuple(self._faults.names)
        self.outbox.flush()
        return FaultAck(acked, remaining)

    # ------------------------------------------------------------------ internals: starting plans
    def _start_plan(
        self,
        goal: Mapping[str, float],
        speed_scale: float,
        kind: str,
        label: str | None,
        *,
        runner: ManeuverRunner | None,
        deadline: float | None = None,
        issued: float | None = None,
        request: int | None = None,
    ) -> MotionAccepted:
        """Plan (outside the control lock) and install a goto/preset/maneuver-step motion.

        A command (``runner`` None) is checked against the mode, the precedence, the faults held,
        its deadline and the latest stop, and aborts a running maneuver; a maneuver step
        (``runner`` its maneuver) is dropped when that maneuver ended meanwhile. The plan starts
        from the predicted state at the switch time; it is made again (up to ``_PLAN_TRIES``
        times) when something else started meanwhile, when the switch time passed while
        planning, or when a measured start pose moved. A switch time after the deadline is
        refused (``busy``): the motion is never started later than asked.
        """
        from_maneuver = runner is not None
        what = label if kind == "preset" and label in ("raise", "return") else kind  # named so in refusals
        if from_maneuver:
            what = f"maneuver {label}"  # "maneuver step 2 (index 1) refused: …"
        lead = _PLAN_LEAD_S
        for _ in range(_PLAN_TRIES):
            with self._lock:
                now = self.clock()
                if not from_maneuver:
                    self._check_startable(kind, now, deadline, issued, what)
                else:  # a step comes when its maneuver gets there: the ECU may have switched off meanwhile
                    self._check_controllers_on(what)
                self._expire_jog(now)  # a dying jog is replaced from its braking plan
                why = link_problem(self.link.status(now), now, self.link.config.stale_after_s)
                if why:
                    raise MotionError("ecu", f"{what} refused: {why}")
                t_switch = now + lead
                start = self._predict(t_switch)
                from_rest = self._active is None and not start.moving  # holding: the start does not age
                gen = self._generation
            t_plan = self.clock()
            wait = None if deadline is None else max(0.0, deadline - t_plan)
            if not self._plan_lock.acquire(timeout=-1 if wait is None else wait):
                raise MotionError("busy", f"{what} refused: the planner stayed busy past its deadline; not run later")
            try:
                gp = self.plan_guard.plan(start, goal, speed_scale=speed_scale)  # PlanError / GuardRefusal
                tail = self._count_tail(gp.plan) if kind in _COUNT_APPROACH_KINDS else None
            finally:
                self._plan_lock.release()
            took = self.clock() - t_plan
            events: list[Event] = []
            with self._lock:
                if from_maneuver and not self._maneuver.owns(runner, request):
                    raise MotionError("busy", "the maneuver was aborted while its step was being planned")
                if not from_maneuver:
                    self._check_startable(kind, self.clock(), deadline, issued, what)
                if self._generation != gen:
                    continue  # something else started meanwhile: re-plan from it
                now = self.clock()
                if from_rest and self._active is None:
                    if self._hold is None and np.max(np.abs(self._predict(now).position - start.position)) > _MOVED:
                        continue  # the measured start moved while planning (coasting): again
                    t_switch = max(t_switch, now)  # from rest the plan may start whenever it is ready
                elif now > t_switch - 0.25 * self.dt:
                    lead = max(2 * lead, 1.5 * took + self.dt)  # planning took longer: again, further ahead
                    continue
                if deadline is not None and t_switch > deadline + 1e-9:
                    raise MotionError(
                        "busy",
                        f"{kind} refused: it could start moving only {t_switch - deadline:.3f} s after its "
                        "deadline (planning took too long); not run later",
                    )
                prev = self._active if isinstance(self._active, PlanMotion) else None
                if self._active is not None:
                    events.append(self._ev("motion_aborted", self._active, reason=f"replaced by {kind}"))
                if not from_maneuver:
                    self._maneuver.abort(now, "interrupted", f"replaced by {kind}", events)
                pm = PlanMotion(kind, next(self._ids), gp.plan, t_switch, prev, gp.decision, label, tail=tail)
                self._install(pm)
                events.append(
                    self._ev(
                        "motion_started",
                        pm,
                        kind=kind,
                        duration=pm.duration,
                        goal=pose_dict(gp.plan.state_at(gp.plan.duration).position),
                        label=label,
                    )
                )
                if runner is not None:
                    runner.motion_started(pm.motion_id, request)
                acc = MotionAccepted(pm.motion_id, pm.duration, kind, gp.decision)
                self._post(events)
            self.outbox.flush()
            return acc
        raise MotionError("busy", f"{kind} could not be started: the service is too busy to plan in time")

    def _count_tail(self, plan: Plan) -> CountTail | None:
        """The profile's count approach (``motion.count_approach``) to ``plan``'s goal (:mod:`bridge.link.count_tail`),
        checked by the link and the planning guard; None without the setting or where either refuses it. Under
        ``_plan_lock``: the planning guard's model, never the control thread's."""
        return plan_count_tail(self.plan_guard.planner, plan, self.link.check_reference, self.plan_guard)

    def _check_startable(
        self, kind: str, now: float, deadline: float | None, issued: float | None, what: str | None = None
    ) -> None:
        """A command may start now: mode, precedence, no fault held, not cancelled by a later stop,
        its deadline not passed (all O(1), under the lock). ``what`` names it in refusals (default ``kind``:
        a quick raise is a ``preset`` motion, refused as ``raise``)."""
        what = what or kind
        self._check_allowed(what)  # (a raise in transport mode was "preset is refused …": a newcomer's trial)
        self._check_precedence()
        self._check_no_fault(what)
        self._check_controllers_on(what)
        self._check_late(what, now, deadline, issued)

    def _check_controllers_on(self, what: str) -> None:
        """Refused (``ecu``) while the cylinder ECU reports its controllers off (system-state bit 0): it
        would not drive the valves, and the motion would run its plan with nothing moving."""
        ls = self.link.latest_state()
        if ls is not None and not ls.system.controllers_on:
            raise MotionError(
                "ecu",
                f"{what} refused: the cylinder ECU reports its controllers off (system state bit 0): it does not "
                "drive the valves; switch them on at the ECU",
            )

    def check_in_time(self, what: str, deadline: float | None, issued: float | None) -> None:
        """Refuse (``busy``) a request that would start or resume motion after its ``deadline`` [s, this
        controller's clock], or that arrived (``issued``) before the latest stop: never run later."""
        with self._lock:
            self._check_late(what, self.clock(), deadline, issued)

    def _check_late(self, what: str, now: float, deadline: float | None, issued: float | None) -> None:
        if issued is not None and issued <= self._stopped_at:
            raise MotionError("busy", f"{what} cancelled: a stop was sent after this request arrived; not run later")
        if issued is not None and issued - self._stopped_at <= STOP_GRACE_S:
            raise MotionError(
                "busy",
                f"{what} refused: it arrived {1000.0 * (issued - self._stopped_at):.0f} ms after a stop (within "
                f"{1000.0 * STOP_GRACE_S:.0f} ms it may have been sent before the stop); send it again",
            )
        if deadline is not None and now > deadline:
            raise MotionError(
                "busy",
                f"{what} refused: its deadline passed {now - deadline:.3f} s ago (it waited for the service or its "
                "planning took too long; a longer deadline_ms gives it more time); not run later",
            )

    def _check_no_fault(self, kind: str) -> None:
        why = self._faults.refusal(kind)
        if why is not None:
            raise MotionError("ecu", why)

    def _check_allowed(self, what: str) -> None:
        check_mode_allows(self._mode, what)
        if self.guard.implement_limits.transport_locked:  # the implement's transport lock (docs/implements.md)
            raise MotionError(
                "locked",
                f"{what} refused: the implement is transport-locked (unlock it first: `hitch implement unlock`, "
                "key implements/unlock; stop is allowed)",
            )

    def _check_precedence(self) -> None:
        m, work = self._active, self.work
        if isinstance(m, TrackMotion) and not m.ending and work is not None and work.owns(m.session):
            raise MotionError(  # the operator started work, not a track session: say what ends it
                "busy",
                f"work session {m.session} is active (motion {m.motion_id}); end it first: hitch work stop "
                "(key work/stop), or stop",
            )
        check_precedence(m, self.clock())

    def _predict(self, t: float, *, require_link: bool = True) -> MotionState:
        """Commanded state at clock time ``t``: the active motion's, the held one or the measured pose."""
        m = self._active
        if isinstance(m, PlanMotion):
            in_tail = tail_at(m, t)  # at rest on a count approach's counts: what follows starts from them
            return plan_state(m, t) if in_tail is None else in_tail.state
        if isinstance(m, JogMotion):
            return m.jog.state
        if isinstance(m, TrackMotion):
            return m.follower.state
        if self._hold is not None:
            return self._hold
        ls = self.link.latest_state()
        if ls is None:
            if require_link:
                raise MotionError("ecu", "no measurement from the cylinder ECU yet: the start pose is unknown")
            return MotionState.at_rest(self.planner.model.neutral_pose.controlled())
        return MotionState.at_rest(ls.pose.controlled())

    def _brake(self, now: float, reason: str, events: list[Event]) -> int | None:
        """Replace the active motion by the jerk-limited stop from its state now (id of the stop). A goto in its
        count approach is at rest already: it holds the counts streamed now (None: no stop motion)."""
        m = self._active
        if m is None or (isinstance(m, PlanMotion) and m.kind == "stop"):
            return None if m is None else m.motion_id
        events.append(self._ev("motion_aborted", m, reason=reason))
        in_tail = tail_at(m, now) if isinstance(m, PlanMotion) else None
        if in_tail is not None:
            # at rest on a count approach (this goto's, or the one a goto in its lead replaces): hold the counts
            # streamed now (the goal's would move the pistons)
            self._generation += 1  # as a new motion would: plans in flight start again from the hold
            self._active, self._hold, self._hold_ref = None, in_tail.state, None
            self._hold_actuators = in_tail.actuators
            return None
        t0 = m.t_state if isinstance(m, (JogMotion, TrackMotion)) else now  # the time the predicted state belongs to
        sm = PlanMotion("stop", next(self._ids), self.planner.plan_stop(self._predict(now)), t0)
        self._install(sm)
        events.append(self._ev("motion_started", sm, kind="stop", duration=sm.plan.duration))
        return sm.motion_id

    def _expire_jog(self, now: float) -> bool:
        """A jog whose command died becomes its jerk-limited stop, from the state it had at its
        last step (so the reference stays continuous); True if that happened."""
        m = self._active
        if not isinstance(m, JogMotion) or now < m.expires:
            return False
        self._active = PlanMotion("jog", m.motion_id, self.planner.plan_stop(m.jog.state), m.t_state)
        return True

    def _install(self, m: ActiveMotion) -> None:
        self._active = m
        self._last_id = m.motion_id
        self._generation += 1
        self._hold = self._hold_ref = self._hold_actuators = None

    def _abort_all(self, reason: str, now: float, events: list[Event], kind: AbortReason = "fault") -> None:
        """End the motion and the maneuver (its ``maneuver_aborted`` says ``kind``: ``fault`` for what the
        link or the control cycle raised, ``stop`` for the service's own end), with ``reason``."""
        self._maneuver.abort(now, kind, reason, events)
        if self._active is not None:
            events.append(self._ev("motion_aborted", self._active, reason=reason))
        self._active, self._hold, self._hold_ref, self._hold_actuators = None, None, None, None
        self._generation += 1

    # ------------------------------------------------------------------ the control thread
    def _on_cycle_error(self, exc: Exception) -> None:
        """A bug in a cycle: report it, drop the motion, stop the stream, latch ``internal``; the
        loop keeps running."""
        evs: list[Event] = []
        with self._lock:
            now = self.clock()
            self._abort_all(f"internal error: {type(exc).__name__}: {exc}", now, evs)
            self.link.stop_motion()
            msg = f"{type(exc).__name__}: {exc}"
            evs.append(
                {**self._faults.hold(Fault("internal", msg[:300], True, now)), "fault": "internal", "message": msg}
            )
            self._post(evs)
        self.outbox.flush()

    def cycle(self) -> None:
        """One control cycle (public for deterministic tests).

        The link's faults are taken first (a fault raised now ends the motion now), then the state,
        right after the wake-up (stamped then, so its period is as regular as the wake-ups): measured
        pose now, with the reference sent in the previous cycle (the one the ECU is tracking) and the
        faults of the same moment (it said ``online: false`` with no fault and the motion still running
        for one message). Then the motion is advanced and the new reference sent; a track
        session's guard look-ahead and the state's guard evaluations (kinematic margin, stability) are
        computed only after that, so a streamed setpoint reaches the bus without waiting for them.
        Bounded work: no planning, no storage, no serialisation (the outbox does that).
        """
        events: list[Event] = []
        with self._lock:
            now = self.clock()
            status = self.link.status(now)
            self._cycle_n += 1
            due = self._cycle_n % self.state_every == 0 and self.state_wanted()
            self._check_faults(status, now, events)  # first: the state says the faults of its own moment
            state = self._state_draft(now, status) if due else None
            self._drive_maneuver(status, now, events)
            if self.work is not None:  # a work session's z setpoint for this cycle (bridge.service.work)
                self.work.on_cycle(now, self._active, events, self._ended_tracks.get)
            ref = self._reference_at(now, events)
            if ref is not None and not (ref is self._reference and self._active is None and status.streaming):
                # (a held reference the link streams already is not checked and sent again)
                try:
                    self.link.send_reference(streamed_reference(self.shaper, self._active, ref, now), now)
                    self._reference = ref
                except ValueError as exc:  # ReferenceRefused / LinkFaultError: never streamed
                    what = "limit_reached" if isinstance(exc, ReferenceRefused) else "fault"
                    events.append({"event": what, "message": str(exc), "motion_id": self._last_id})
                    self._abort_all(f"reference refused: {exc}", now, events)
                    self.link.stop_motion()
                    if isinstance(exc, LinkFaultError):  # the link's latched faults that are still there
                        self._faults.latch_link(status, now)
            self._supervise_following(status, now, events)
            if isinstance(self._active, TrackMotion):  # its guard look-ahead, after the reference is out
                self._active.look_ahead(self.guard)
            self._post(events)
        if state is not None:  # this thread's guard and cache, outside the lock: requests never wait for it
            self.outbox.put_state(state())
        self.outbox.flush()

    def _supervise_following(self, status: LinkStatus, now: float, events: list[Event]) -> None:
        """The fault ``following_error`` (latching) when a cylinder does not follow the streamed references
        (:mod:`bridge.service.motion.following`): the motion is aborted and the stream stopped, so the ECU's
        watchdog holds the valves at zero. Supervised only while references stream to an ECU whose watchdog
        has not expired, with a fresh measurement (the link's faults cover the rest)."""
        ls, ref = status.state, self._reference
        if not status.streaming or ref is None or ls is None or ls.system.watchdog_tripped or self._faults:
            self.following.reset()
            return
        self.following.streamed(now, ref, ref.actuators, ref.rates)
        if ls.age_s(now) > self.link.config.stale_after_s:
            return
        why = self.following.check(ls.actuators.as_array(), ls.measurement_t_s, ls.lift_t_s)
        if why is None:
            return
        events.append(self._faults.hold(Fault(FOLLOWING_ERROR, why, True, now)))
        self._abort_all("following error: " + why, now, events)
        self.link.stop_motion()
        self.following.reset()

    def _check_faults(self, status: LinkStatus, now: float, events: list[Event]) -> None:
        """The fault policy (:meth:`FaultBook.review`, ``docs/faults.md``): a fault the link raised since the
        last cycle aborts everything (an old plan never resumes) and stops the stream."""
        event = self._faults.review(status, now)
        if event is None:
            return
        events.append(event)
        if event["event"] == "fault" and (self._active is not None or self._hold is not None or self._maneuver.running):
            self._abort_all("link fault: " + event["message"], now, events)
            self.link.stop_motion()

    def _drive_maneuver(self, status: LinkStatus, now: float, events: list[Event]) -> None:
        m, runner, ls = self._active, self._maneuver.runner, status.state
        if isinstance(m, PlanMotion) and m.finished(now):  # a step's motion ends before its maneuver goes on
            self._announce_finished(m, events)
        loop = LoopState(
            isinstance(m, PlanMotion) and not m.finished(now), self._last_id, None if ls is None else ls.measurement_t_s
        )
        cmd = self._maneuver.tick(now, loop, self._odometer(), events)
        # a resume's or skip's deadline holds for the motion its first tick starts, and for nothing later
        deadline, self._resume_deadline = self._resume_deadline, None
        if cmd is None:
            return
        if cmd.action == "goto" and runner is not None and cmd.goal is not None:  # a running maneuver's motion step
            goal, scale, step, owner, req = dict(cmd.goal), cmd.speed_scale, cmd.step, runner, cmd.request
            self._spawn(lambda: self._maneuver_goto(owner, goal, scale, step, req, deadline))
        elif cmd.action == "stop":
            self._brake(now, "maneuver aborted", events)

    def _maneuver_goto(
        self,
        runner: ManeuverRunner,
        goal: Mapping[str, float],
        scale: float,
        step: int | None,
        request: int | None = None,
        deadline: float | None = None,
    ) -> None:
        named = "a step" if step is None else step_words(step)
        try:
            self._start_plan(goal, scale, "maneuver", named, runner=runner, request=request, deadline=deadline)
        except ValueError as exc:
            events: list[Event] = []
            late = isinstance(exc, MotionError) and exc.code == "busy" and deadline is not None
            refused = isinstance(exc, MotionError) and not late  # the link or the ECU not ready: says why
            reason: AbortReason = "deadline" if late else "refused" if refused else "plan_failed"
            text = f"{named}: {exc}" if late else str(exc) if refused else f"{named} cannot be planned: {exc}"
            with self._lock:
                if self._maneuver.owns(runner, request):
                    self._maneuver.abort(self.clock(), reason, text, events)
                self._post(events)
            self.outbox.flush()

    def _announce_finished(self, m: PlanMotion, events: list[Event]) -> None:
        """``motion_finished`` of the plan ``m`` at its end, once (the maneuver's tick may come first)."""
        if not m.announced:
            extra = {"reason": "released: no jog command within its ttl, braked to rest"} if m.kind == "jog" else {}
            events.append(self._ev("motion_finished", m, kind=m.kind, **extra))
            m.announced = True

    def _reference_at(self, now: float, events: list[Event]) -> Reference | None:
        m = self._active
        if isinstance(m, PlanMotion):
            if m.prev is not None and now >= m.t0:
                m.prev = None
            st = plan_state(m, now)
            self._limited = {} if m.finished(now) else m.limited()
            in_tail = tail_at(m, now)  # a count approach (this goto's, or the one it replaces in its lead)
            if m.finished(now):
                self._announce_finished(m, events)
                if in_tail is not None:  # held on the final counts from this cycle on, at their pose
                    st = in_tail.state
                self._active, self._hold, self._hold_ref = None, MotionState.at_rest(st.position), None
                self._hold_actuators = None if in_tail is None else in_tail.actuators
            elif in_tail is not None:  # its counts and their pose
                return Reference(in_tail.state, in_tail.actuators, np.zeros_like(in_tail.actuators))
        elif isinstance(m, JogMotion):
            if self._expire_jog(now):
                return self._reference_at(now, events)
            out, evs = m.step(self.guard)
            m.t_state = now
            events.extend(evs)
            self._limited = dict(m.limited)
            return Reference(out.state, out.actuators, out.actuator_velocity)
        elif isinstance(m, TrackMotion):
            tout, evs = m.step(self.guard, now)
            events.extend(evs)
            self._limited = dict(m.limited)
            ref = Reference(tout.state, tout.actuators, tout.actuator_velocity)
            if m.follower.finished:
                events.append(self._ev("motion_finished", m, kind="track", session=m.session, reason=m.reason))
                self._active, self._hold, self._hold_ref = None, MotionState.at_rest(tout.state.position), None
                self._hold_actuators = None
                self._limited = {}
            return ref
        elif self._hold is not None:
            if self._hold_ref is not None:  # at rest: nothing changed, nothing recomputed
                return self._hold_ref
            st = self._hold
        else:
            self._limited = {}
            return None
        try:
            q, jac, _ = self.planner.inverse.solve_full(st.position)
        except KinematicsError as exc:
            events.append({"event": "limit_reached", "message": f"reference not reachable: {exc}"})
            self._abort_all(f"reference not reachable: {exc}", now, events)
            return None
        if self._active is None and self._hold_actuators is not None:  # held on the count approach's counts
            ref = Reference(st, self._hold_actuators, np.zeros_like(self._hold_actuators))
        else:
            ref = Reference(st, q, jac @ st.velocity)
        if m is None:
            self._hold_ref = ref
        return ref

    # ------------------------------------------------------------------ state and events
    def _state_message(self, now: float, status: LinkStatus) -> StateMessage:
        return self._state_draft(now, status)()

    def _state_draft(self, now: float, status: LinkStatus) -> Callable[[], StateMessage]:
        """The state as it is now (call under the lock; stamped now), as a function that adds the
        guard's evaluations when called (on the control thread: its guard and cache)."""
        self._seq += 1
        m = self._active
        kind = (
            None
            if m is None
            else (m.kind if isinstance(m, PlanMotion) else "jog" if isinstance(m, JogMotion) else "track")
        )
        ref = self._reference if (m is not None or self._hold is not None) else None
        stale_after_s = self.link.config.stale_after_s
        faults = self._faults.held
        return partial(
            build_state_message,
            seq=self._seq,
            now=now,
            status=status,
            stale_after_s=stale_after_s,
            guard=self.guard,
            mode=self._mode,
            motion_kind=kind,
            motion_id=self._last_id,
            reference=ref,
            limited=dict(self._limited),
            maneuver=self._maneuver.progress(),
            feedforward=self.shaper,
            faults=faults,
            cache=self._eval_cache,
            track=m.progress() if isinstance(m, TrackMotion) else None,
            goal=self._goal_of(m) if isinstance(m, PlanMotion) else None,
            work=None if self.work is None else self.work.progress(),
            t=time.time(),
            ecu=EcuSummary.of(status, now, stale_after_s, self.shaper, faults),
        )

    def _goal_of(self, m: PlanMotion) -> dict[str, Any] | None:
        """The state's ``goal`` of plan motion ``m``: computed once per plan, not every cycle."""
        if self._goal_plan is not m.plan:
            self._goal_plan, self._goal = m.plan, plan_goal(m.kind, m.plan)
        return self._goal

    def _not_live(self, session: int, m: ActiveMotion | None) -> str:
        """Why ``session`` takes no setpoint or stop: how it ended (when it is one of the last few) and which
        session is live."""
        live = f"the live session is {m.session}" if isinstance(m, TrackMotion) else "no session is live"
        ended = self._ended_tracks.get(session)
        return f"session {session} is not live ({f'it ended: {ended}; ' if ended else ''}{live})"

    def _ev(self, name: str, m: ActiveMotion, **extra: Any) -> Event:
        if isinstance(m, TrackMotion) and name in ("motion_finished", "motion_aborted"):
            self._ended_tracks[m.session] = str(extra.get("reason") or name.removeprefix("motion_"))
            while len(self._ended_tracks) > ENDED_TRACKS_KEPT:
                del self._ended_tracks[next(iter(self._ended_tracks))]
        return {"event": name, "motion_id": m.motion_id, **{k: v for k, v in extra.items() if v is not None}}

    def _post(self, events: list[Event]) -> None:
        """Number and queue ``events`` (call under the lock: the numbering is the order things
        happened in); :meth:`Outbox.flush` after the lock delivers them. Each gets where the hitch was:
        ``measured_pose`` (the link's newest measured pose [m, rad]) and ``measured_age_s`` (its age [s] on the
        link's clock: a link fault's pose is from before the link went quiet), when there was a measurement
        (an incident trial: the black box said that a fault came, not where the implement was)."""
        if not events:  # called every cycle: nothing to number, nothing to look up
            return
        ls = self.link.latest_state()
        where: dict[str, Any] = {}
        if ls is not None:
            where = {
                "measured_pose": {k: round(float(v), 6) for k, v in ls.pose.as_dict().items()},
                "measured_age_s": round(max(0.0, float(self.clock()) - float(ls.t_s)), 4),
            }
        for e in events:
            self.outbox.put_event({**where, **e} if where else e)


def _maneuver_words(event: Mapping[str, Any]) -> str:
    """A maneuver event's maneuver in words: its name quoted, else its id ("maneuver None" for one run unnamed,
    a review), else "(unnamed)"."""
    name, mid = event.get("maneuver"), event.get("maneuver_id")
    if name:
        return repr(name)
    return f"#{mid}" if mid is not None else "(unnamed)"
