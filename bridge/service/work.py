"""Work control in the live service: position, draft, mixed and float control of a track session.

:class:`WorkControl` runs next to the :class:`~bridge.service.motion.controller.MotionController` (in the
service's threads or in the control core's process): ``start`` opens a track session (frame
``tractor``, DOF z; the precedence of track mode: refused while a stop brakes or a jog is live, takes
over a goto), and every control cycle of that session the motion controller calls :meth:`WorkControl.on_cycle`
(under its lock, before the reference is computed), which runs :meth:`planner.work_control.WorkController.step`
and hands its z to the session's :class:`~planner.trajectory.track.TrackFollower` as the setpoint
(with its rate). The follower, the workspace, the implement's bounds and the guard act on that z as
on any other setpoint: what clipped it is named in ``limited`` (the depth limits as
``work:depth_min`` / ``work:depth_max``, the workspace as ``workspace:z:min`` …).

Inputs (:class:`SensorWorkInputs`): the draft is :meth:`bridge.link.tractor_sensors.TractorSensors.draft`
(RearDraft of PGN 65093; the service reads it with ``read_draft``), the ground reference
``ground_z = z_measured - ground_distance + tool_drop_m`` from the ground-distance sensor (as the
field loop, ``docs/soil.md``), the slip: None — the tractor's slip is not on the bus in this project
(the work block says so; slip limiting then holds its integral).

A fallback (a stale or implausible draft, no ground reference) is one ``work_fallback`` event with the
reason; the session goes on in position control until ``work/resume`` (or new settings).

API side (:func:`work_handlers`): ``work/settings`` (get: the selected implement's settings, defaults if
none stored, with the live status; put: validated, persisted per implement in the store, applied to a
live session), ``work/start`` (the selected implement's settings), ``work/stop``, ``work/resume``. With
the core in its own process the calls travel as ``work`` calls (:meth:`WorkControl.dispatch`).

The twin (:func:`sim_field_tractor`): with ``sim_field`` configured the simulated tractor drives over the
field's terrain scenario and the ECU node's draft source is a :class:`~bridge.sim.field.FieldDraft`
stepped with the tool tip's true height, so the draft pins are on the bus; without it the hitch status
carries no draft and draft mode falls back at once ("draft signal stale: no reading").
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any, NoReturn, Protocol

import numpy as np

from bridge.service.motion.types import MotionError, TrackMotion
from bridge.service.store import DEFAULT_IMPLEMENT
from planner.errors import HitchError
from planner.model.hard_limits import WORKSPACE_NAMES
from planner.trajectory.track import subset_limits
from planner.work_control import WorkController, WorkSettings, WorkSettingsError, WorkStatus

__all__ = [
    "DEFAULT_WORKING_DEPTH_M",
    "SETTINGS_FIELDS",
    "WORK_TTL_S",
    "SensorWorkInputs",
    "WorkControl",
    "WorkInputs",
    "WindowSlope",
    "Z_RATE_SHARE",
    "call_work",
    "draft_rate_limit",
    "settings_from_json",
    "settings_to_json",
    "sim_field_tractor",
    "simulated_ground_speed",
    "tool_drop_m",
    "unused_sim_terrain",
    "work_handlers",
]

#: the work session's setpoint time-to-live [s] (the control cycle feeds it every 20 ms)
WORK_TTL_S = 0.3
#: the tool's working depth at the operator's z = 0 when no field says otherwise [m] (tool geometry assumption)
DEFAULT_WORKING_DEPTH_M = 0.2
#: the operator's settings the API takes (SI); the rest of WorkSettings keeps its defaults
SETTINGS_FIELDS = ("mode", "draft_setpoint_n", "blend", "sensitivity", "depth_min_m", "depth_max_m", "slip_limit")
_SLIP_NOTE = "slip unavailable: the tractor's slip is not on the bus"
_RATE_WINDOW_S = 0.1


def settings_to_json(s: WorkSettings) -> dict[str, Any]:
    """The operator's fields of ``s`` (JSON-ready, SI)."""
    return {k: getattr(s, k) for k in SETTINGS_FIELDS}


def settings_from_json(data: Mapping[str, Any], base: WorkSettings | None = None) -> WorkSettings:
    """``base`` (default: the defaults) with the fields of ``data`` replaced; validated.

    Raises:
        WorkSettingsError: an unknown field, or a value outside its range (the message names both).
    """
    if not isinstance(data, Mapping):
        raise WorkSettingsError(f"work settings must be an object, got {type(data).__name__}")
    unknown = sorted(set(data) - set(SETTINGS_FIELDS))
    if unknown:
        raise WorkSettingsError(f"unknown work settings {unknown}; allowed: {', '.join(SETTINGS_FIELDS)}")
    merged = {**settings_to_json(base if base is not None else WorkSettings()), **dict(data)}
    return WorkSettings(**merged)


def tool_drop_m(pivot_height_m: float, working_depth_m: float | None = None) -> float:
    """The tool tip's drop below the tool point T [m]: the operator's z = 0 works at ``working_depth_m``
    (default :data:`DEFAULT_WORKING_DEPTH_M`) below the contact plane (``docs/soil.md``, field loop)."""
    return float(pivot_height_m) + (DEFAULT_WORKING_DEPTH_M if working_depth_m is None else float(working_depth_m))


class WorkInputs(Protocol):
    """What work control reads each cycle (fresh, plausible readings or None)."""

    def draft(self, now: float) -> tuple[float | None, float | None]:
        """(draft [N] or None, its receive time [s] or None)."""
        ...

    def slip(self, now: float) -> float | None: ...

    def ground_z(self, now: float) -> float | None:
        """The hitch height at which the tool tip touches the ground (tractor frame) [m]."""
        ...


class SensorWorkInputs:
    """:class:`WorkInputs` from the tractor's sensors on the bus (module docstring).

    Args:
        sensors: a :class:`~bridge.link.tractor_sensors.TractorSensors` (``read_draft`` on).
        measured_z: the measured hitch z now [m] (None: no measurement yet).
        tool_drop_m: the tool tip's drop below T [m] (:func:`tool_drop_m`).
    """

    def __init__(self, sensors: Any, measured_z: Callable[[], float | None], tool_drop_m: float) -> None:
        self.sensors, self.measured_z, self.tool_drop_m = sensors, measured_z, float(tool_drop_m)

    def draft(self, now: float) -> tuple[float | None, float | None]:
        r = self.sensors.draft(now)
        return (None if r.value is None else float(r.value)), r.received_s

    def slip(self, now: float) -> float | None:
        return None  # not on the bus (module docstring)

    def ground_z(self, now: float) -> float | None:
        g = self.sensors.readings(now).ground_distance
        z = self.measured_z()
        if not g.usable or g.value is None or z is None:
            return None
        return float(z) - float(g.value) + self.tool_drop_m


class WindowSlope:
    """Least-squares slope of the samples within the last ``window_s`` [unit/s] (0 with fewer than two
    samples or no spread in time): a rate from noisy samples, for work control and the simulated loops."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self._buf: deque[tuple[float, float]] = deque()

    def add(self, t: float, v: float) -> float:
        self._buf.append((t, v))
        while self._buf and self._buf[0][0] < t - self.window_s - 1e-9:
            self._buf.popleft()
        n = len(self._buf)
        if n < 2:
            return 0.0
        tm = sum(p[0] for p in self._buf) / n
        vm = sum(p[1] for p in self._buf) / n
        den = sum((p[0] - tm) ** 2 for p in self._buf)
        return 0.0 if den <= 0.0 else sum((p[0] - tm) * (p[1] - vm) for p in self._buf) / den


Z_RATE_SHARE = 0.9
"""The share of the follower's z speed the draft regulator may use (the rest: the follower's own
corrections and the ground's motion, which moves the depth limits)."""


def draft_rate_limit(planner: Any, pose: Any) -> float:
    """What the draft regulator may ask of the hitch at ``pose``: :data:`Z_RATE_SHARE` times the z speed
    the track follower allows a z-only session (its subset limits, z alone) [m/s]."""
    active = np.array([False, True, False, False])
    lim = subset_limits(planner.inverse, np.asarray(pose, float), active, planner.limits, planner.lo, planner.hi)
    v = float(planner.any_direction.velocity[1]) if lim is None else float(lim.velocity[1])
    return Z_RATE_SHARE * v


def _reachable_z(follower: Any) -> tuple[float, float, tuple[str, str]]:
    """The z range the session's follower keeps its setpoints in (the workspace's faces, the top lowered by
    the session's bounds: an implement's upper height) and the names of its faces (``workspace:z:min`` …)."""
    lo, hi = float(follower.lo[1]), float(follower.hi[1])
    names = getattr(follower, "_names", WORKSPACE_NAMES)[1]
    return lo, hi, (str(names[0]), str(names[1]))


class WorkControl:
    """Work sessions on a motion controller (module docstring). API calls from any thread;
    :meth:`on_cycle` from the control cycle under the controller's lock. Its own lock is held only for
    O(1) swaps and never while calling the controller (so the lock order is always controller → this)."""

    def __init__(self, motion: Any, inputs: WorkInputs | None) -> None:
        self.motion, self.inputs = motion, inputs
        self._lock = threading.Lock()
        self._settings = WorkSettings()
        self._json_of: WorkSettings | None = None  # the settings whose JSON ``_json`` holds
        self._json: dict[str, Any] = {}
        self._pending: WorkSettings | None = None
        self._resume = False
        self._session: int | None = None
        self._z_op = 0.0
        self._ctl = WorkController(self._settings)
        self._slope = WindowSlope(_RATE_WINDOW_S)
        self._last: WorkStatus | None = None
        self._limited: dict[str, str] = {}
        self._draft: float | None = None
        self._ended: str | None = None
        self._end_reason: str | None = None  # why the session's track ends (pause); None: it just ended
        self.fallbacks = 0
        self.rejected = 0
        self.last_rejection: str | None = None
        #: plain ``track/setpoint`` messages for the work session's id (refused: work control alone feeds it)
        self.foreign_setpoints = 0

    # ------------------------------------------------------------------ API (any thread)
    def dispatch(self, op: str, *args: Any) -> dict[str, Any]:
        """``configure`` (settings JSON), ``start`` (settings JSON, z or None), ``stop``, ``resume``, ``pause``
        (deadline, issued, reason), ``status``."""
        if op == "configure":
            return self.configure(settings_from_json(args[0]))
        if op == "start":
            timing = dict(zip(("deadline", "issued"), args[2:4], strict=False))
            return self.start(settings_from_json(args[0]), None if len(args) < 2 else args[1], **timing)
        if op == "stop":
            return self.stop()
        if op == "resume":
            return self.resume(*args[:2])
        if op == "pause":
            return self.pause(*args[:3])
        if op == "status":
            return self.progress()
        raise WorkSettingsError(f"work: op must be one of configure, start, stop, resume, pause, status, got {op!r}")

    def configure(self, settings: WorkSettings) -> dict[str, Any]:
        """New settings: a live session takes them on its next cycle (bumpless; a fallback is cleared)."""
        with self._lock:
            self._settings = settings
            if self._session is not None:
                self._pending = settings
        return self.progress()

    def start(
        self,
        settings: WorkSettings,
        z: float | None = None,
        *,
        deadline: float | None = None,
        issued: float | None = None,
    ) -> dict[str, Any]:
        """Start a work session: a track session (tractor frame, z) fed by work control. ``z``: the
        operator's position setpoint [m] (None: the commanded z now). ``deadline`` and ``issued`` as for
        :meth:`~bridge.service.motion.controller.MotionController.track_start`. Raises MotionError as
        track/start."""
        if z is not None and (isinstance(z, bool) or not isinstance(z, (int, float)) or not math.isfinite(z)):
            raise WorkSettingsError(f"z must be a finite number [m], got {z!r}")
        self.motion.check_in_time("start", deadline, issued)
        here = self.motion.current_state().position
        z_op = float(z) if z is not None else float(here[1])
        rate = draft_rate_limit(self.motion.planner, here)  # the draft demand never outruns the hitch
        with self._lock:
            own = self._session  # work/start again: its own live session is taken over, another one is not
        acc = self.motion.track_start(
            "tractor",
            ("z",),
            WORK_TTL_S,
            deadline=deadline,
            issued=issued,
            replace=own if own is not None else False,
            caller="work/start",
        )
        with self._lock:
            old = self._session  # replaced by this one: it finished (it ended without a word: a new user's report)
            self._settings = settings
            self._ctl = WorkController(settings, z_rate_max_m_s=rate)
            self._z_op = z_op
            self._slope = WindowSlope(_RATE_WINDOW_S)
            self._pending, self._resume = None, False
            self._last, self._limited, self._ended, self._end_reason = None, {}, None, None
            self._draft = None
            self.fallbacks = self.rejected = self.foreign_setpoints = 0
            self._session = int(acc.session)
        if old is not None and old != self._session:
            self.motion.post_event(
                {"event": "work_finished", "session": old, "reason": f"replaced by work/start (session {acc.session})"}
            )
        return {**acc.to_json(), "work": self.progress()}

    def stop(self) -> dict[str, Any]:
        """End the work session smoothly (the track session's stop)."""
        with self._lock:
            session = self._session
        if session is None:
            raise MotionError("not_found", "no work session is running (work/start)")
        reply = self.motion.track_stop(session)
        return {**reply, "work": self.progress()}

    def resume(self, deadline: float | None = None, issued: float | None = None) -> dict[str, Any]:
        """Clear a latched fallback: the configured mode engages again (bumpless). ``deadline`` and
        ``issued`` as for :meth:`~bridge.service.motion.controller.MotionController.goto`: a resume
        that comes too late, or before a later stop, is refused ``busy``."""
        self.motion.check_in_time("resume", deadline, issued)
        with self._lock:
            if self._session is None:
                raise MotionError("not_found", "no work session is running (work/start)")
            self._resume = True
        return self.progress()

    def pause(
        self, deadline: float | None = None, issued: float | None = None, reason: str = "paused"
    ) -> dict[str, Any]:
        """End a running work session smoothly for a motion that takes over (the operator's quick raise at
        the headland): ``{"paused": {"session", "z", "mode"}}`` (the operator's z [m] and the mode, for the
        work that starts again after it) or ``{"paused": None}`` when none runs. ``deadline`` and ``issued``
        as for :meth:`resume`: a request too late, or sent before a later stop, ends nothing (``busy``).
        ``reason`` goes into the ``work_finished`` event."""
        self.motion.check_in_time(reason, deadline, issued)
        with self._lock:
            session, z_op, mode = self._session, self._z_op, self._settings.mode
            if session is None:
                return {"paused": None}
            self._end_reason = reason
        try:
            self.motion.track_stop(session)
        except MotionError:  # it ended meanwhile (a stop, a jog): nothing to pause, the stop's reason stands
            with self._lock:
                self._end_reason = None
            return {"paused": None}
        return {"paused": {"session": session, "z": z_op, "mode": mode}}

    def owns(self, session: int) -> bool:
        """Whether ``session`` is the live work session (its setpoints come from work control alone)."""
        return self._session is not None and self._session == session

    def refuse_setpoint(self, motion: TrackMotion) -> NoReturn:
        """A plain ``track/setpoint`` for the work session (called by the motion controller under its
        lock): it must not compete with work control. Counted here (``setpoints_refused``) and in the
        session's ``rejected``; raises MotionError ``busy`` (a put's reply goes nowhere)."""
        text = (
            f"session {motion.session} is a work session: its setpoints come from work control "
            "(work/settings, work/stop), track/setpoint is refused"
        )
        with self._lock:
            self.foreign_setpoints += 1
        motion.rejected += 1
        motion.last_rejection = text
        raise MotionError("busy", text)

    # ------------------------------------------------------------------ the control cycle
    def on_cycle(
        self,
        now: float,
        active: Any,
        events: list[dict[str, Any]],
        ended: Callable[[int], str | None] | None = None,
    ) -> None:
        """One control cycle (under the controller's lock): the work controller's z to the live session.
        ``ended``: how a track session ended (its abort or finish reason), for the ``work_finished`` event."""
        with self._lock:
            session = self._session
            if session is None:
                return
            if not isinstance(active, TrackMotion) or active.session != session:
                self._session = None
                why = None if ended is None else ended(session)
                # the cause, not only that it ended (a safety trial: a fault, a lost link and references_lost
                # all read "the track session ended")
                self._ended = self._end_reason or (
                    f"the track session ended: {why}" if why else "the track session ended"
                )
                events.append({"event": "work_finished", "session": session, "reason": self._ended})
                return
            pending, self._pending = self._pending, None
            resume, self._resume = self._resume, False
        if active.ending:
            return
        ctl = self._ctl
        if pending is not None:
            ctl.configure(pending)
        elif resume:
            ctl.resume()
        draft_n, draft_t, slip, ground = None, None, None, None
        if self.inputs is not None:
            draft_n, draft_t = self.inputs.draft(now)
            slip = self.inputs.slip(now)
            ground = self.inputs.ground_z(now)
        self._draft = draft_n
        z_lo, z_hi, z_names = _reachable_z(active.follower)
        st = ctl.step(
            now, self._z_op, draft_n=draft_n, draft_t=draft_t, slip=slip, ground_z=ground, z_range=(z_lo, z_hi)
        )
        if st.event is not None:
            self.fallbacks += 1
            events.append(
                {"event": "work_fallback", "session": session, "mode": st.mode, "reason": st.fallback, "t": now}
            )
        limited: dict[str, str] = {}
        s = ctl.settings
        if st.active in ("draft", "mixed", "float") and st.depth_m is not None:
            if st.depth_m >= s.depth_max_m - 1e-6:
                limited["depth"] = "work:depth_max"
            elif st.depth_m <= s.depth_min_m + 1e-6 and st.active != "float":
                limited["depth"] = "work:depth_min"
        if st.z_limit is not None:  # the demand held at the face it cannot pass (the follower sees it inside)
            limited["z"] = z_names[0] if st.z_limit == "min" else z_names[1]
        try:
            sp = active.follower.set_setpoint({"z": st.z}, {"z": self._slope.add(now, st.z)}, now)
            active.accepted += 1
            limited.update(sp.limited)
        except HitchError as exc:  # a setpoint the follower cannot take (stopping): counted, named
            self.rejected += 1
            self.last_rejection = str(exc)
        self._last, self._limited = st, limited

    # ------------------------------------------------------------------ state
    def progress(self) -> dict[str, Any]:
        """The state message's ``work`` block (SI: draft [N], depth [m], z [m])."""
        with self._lock:  # one consistent snapshot (on_cycle swaps them together)
            session, s = self._session, self._settings
            running = session is not None
            # the live fields describe the running session only: after it ended they are null/empty (the
            # last session's numbers described an implement that may be out of the soil by now; ``ended``
            # says how it ended)
            st = self._last if running else None
            draft = self._draft if running else None
            limited = dict(self._limited) if running else {}
        action = "none"
        if st is not None and st.slip_limited:
            action = f"raise {st.slip_raise_m:.3f} m" if st.slip_raise_m > 0 else f"cut {st.slip_cut:.2f}"
        return {
            "running": running,
            "session": session,
            "mode": s.mode,
            "active": None if st is None else st.active,
            "fallback": None if st is None else st.fallback,
            "draft_n": draft,
            "draft_setpoint_n": s.draft_setpoint_n,
            "depth_m": None if st is None else st.depth_m,
            "z_operator": self._z_op if running else None,
            "z_setpoint": None if st is None else st.z,
            "slip": None,
            "slip_action": action,
            "slip_note": _SLIP_NOTE if s.slip_limit is not None or s.mode != "position" else None,
            "limited": limited,
            "fallbacks": self.fallbacks,
            "rejected": self.rejected,
            "setpoints_refused": self.foreign_setpoints,
            "ended": self._ended,
            "settings": self._settings_json(s),
        }

    def _settings_json(self, s: WorkSettings) -> dict[str, Any]:
        """``settings_to_json(s)``, computed once per settings value (the state message asks every cycle)."""
        if self._json_of is not s:
            self._json_of, self._json = s, settings_to_json(s)
        return dict(self._json)


def _explicit_ground_speed(cfg: Any) -> float | None:
    """``cfg.sim_ground_speed`` when the user gave it (a config file or a flag; a pydantic config knows which of
    its fields were set), else None (the default: a field's scenario then keeps its own speed)."""
    v = getattr(cfg, "sim_ground_speed", None)
    fields_set = getattr(cfg, "model_fields_set", None)
    if v is None or (fields_set is not None and "sim_ground_speed" not in fields_set):
        return None
    return float(v)


def _at_user_speed(cfg: Any, scenario: Any, key: str, error: type[Exception]) -> Any:
    """``scenario`` (a :class:`~bridge.sim.scenario.Scenario`) driven at ``sim_ground_speed`` (constant) when the
    user gave one, which wins over the scenario's own speed; ``error`` names ``key`` when that speed cannot be."""
    from dataclasses import replace

    from bridge.sim.terrain import SpeedProfile, TerrainError

    v = _explicit_ground_speed(cfg)
    if v is None:
        return scenario
    try:
        speed = SpeedProfile.constant(v)
    except TerrainError as exc:
        raise error(f"sim_ground_speed = {v:g} m/s with {key} {getattr(cfg, key)!r}: {exc}") from None
    return replace(scenario, twin=replace(scenario.twin, speed=speed))


def _sim_field_setup(cfg: Any) -> Any:
    """The field of ``cfg.sim_field`` as the twin drives it: at ``sim_ground_speed`` (constant) when the user
    gave one, which wins over the scenario's speed; else at the scenario's own speed. None: no field."""
    name = getattr(cfg, "sim_field", None)
    if name is None:
        return None
    from dataclasses import replace

    from bridge.sim.field import FieldError, load_field

    fs = load_field(name)
    return replace(fs, scenario=_at_user_speed(cfg, fs.scenario, "sim_field", FieldError))


def _sim_scenario_setup(cfg: Any) -> Any:
    """The track scenario of ``cfg.sim_scenario`` as the twin drives it (at ``sim_ground_speed`` when the user
    gave one, as :func:`_sim_field_setup`); None: none configured."""
    name = getattr(cfg, "sim_scenario", None)
    if name is None:
        return None
    from bridge.sim.scenario import ScenarioError, load_scenario

    return _at_user_speed(cfg, load_scenario(name), "sim_scenario", ScenarioError)


def simulated_ground_speed(cfg: Any) -> float | None:
    """The ground speed the simulated tractor actually drives [m/s] (for the ``config`` reply): without a field
    or scenario ``cfg.sim_ground_speed``; with one, ``sim_ground_speed`` when the user gave it, else the
    scenario's constant speed (None: its speed varies over time, a speed profile). None without a simulated ECU."""
    if not getattr(cfg, "simulate_ecu", True):
        return None
    fs = _sim_field_setup(cfg)
    sc = fs.scenario if fs is not None else _sim_scenario_setup(cfg)
    if sc is None:
        return float(cfg.sim_ground_speed)
    speeds = set(sc.twin.speed.speeds_m_s)
    return float(next(iter(speeds))) if len(speeds) == 1 else None


def unused_sim_terrain(cfg: Any) -> list[str]:
    """A start warning when ``sim_scenario`` or ``sim_field`` is given but no simulated tractor runs
    (``simulate_ecu = false``, ``--no-sim-ecu``): they were ignored without a word (a review; the ``config``
    reply's ``can.simulated_scenario`` only says None)."""
    if getattr(cfg, "simulate_ecu", True):
        return []
    named = [f"{k} {getattr(cfg, k)!r}" for k in ("sim_scenario", "sim_field") if getattr(cfg, k, None) is not None]
    if not named:
        return []
    return [f"{' and '.join(named)}: not used: simulate_ecu = false (--no-sim-ecu), no simulated tractor runs"]


def sim_scenario_tractor(cfg: Any, bus: Any, height: Callable[[float], float | None]) -> Any:
    """The twin's tractor over ``cfg.sim_scenario`` (a track scenario: terrain, slope, row signal; no draft);
    None when none is configured. Its sensors' messages are those of ``hitch sim track`` (slope sensor, ground
    distance, row camera, wheel speed: :class:`~bridge.sim.tractor_node.TractorTwinNode`)."""
    sc = _sim_scenario_setup(cfg)
    if sc is None:
        return None
    from bridge.sim.sensors import TwinSensors
    from bridge.sim.tractor_node import TractorTwinNode

    return TractorTwinNode(bus, TwinSensors(sc.twin), hitch_height_m=height)


def sim_field_tractor(
    cfg: Any, bus: Any, height: Callable[[float], float | None], ecu_node: Any, pivot_height_m: float
) -> Any:
    """The twin's tractor over ``cfg.sim_field`` (its terrain scenario) with the field's draft on the
    ECU node (module docstring); None when no field is configured. The twin drives at ``sim_ground_speed``
    when the user gave it (config file or flag), else at the scenario's speed (:func:`simulated_ground_speed`
    says which); the field's draft and the tractor's wheel speed and GNSS all follow that one speed."""
    fs = _sim_field_setup(cfg)
    if fs is None:
        return None
    from bridge.sim.field import FieldDraft, FieldRun
    from bridge.sim.sensors import TwinSensors
    from bridge.sim.tractor_node import TractorTwinNode

    drop = tool_drop_m(pivot_height_m, fs.working_depth_m)

    def tip_z() -> float:
        h = height(0.0)  # pivot height + the true tool point z
        return -fs.working_depth_m if h is None else float(h) - drop

    ecu_node.draft_source = FieldDraft(FieldRun(fs), tip_z)
    return TractorTwinNode(bus, TwinSensors(fs.scenario.twin), hitch_height_m=height)


def field_working_depth(cfg: Any) -> float | None:
    """The configured sim field's working depth [m] (None: no field)."""
    name = getattr(cfg, "sim_field", None)
    if name is None:
        return None
    from bridge.sim.field import load_field

    return float(load_field(name).working_depth_m)


def build_work_control(cfg: Any, motion: Any, sensors: Any, link: Any, pivot_height_m: float) -> WorkControl:
    """Work control of ``motion`` on the tractor's ``sensors`` and the ``link``'s measured z."""

    def measured_z() -> float | None:
        ls = link.latest_state()
        return None if ls is None else float(ls.pose.controlled()[1])

    drop = tool_drop_m(pivot_height_m, field_working_depth(cfg))
    return WorkControl(motion, SensorWorkInputs(sensors, measured_z, drop))


# ---------------------------------------------------------------------- the API keys
def call_work(motion: Any, op: str, *args: Any) -> dict[str, Any]:
    """:meth:`WorkControl.dispatch` of ``motion``'s work control: in the core process through its proxy
    (``motion.work_call``), in the service's threads directly (``motion.work``); ``unavailable`` without one."""
    remote = getattr(motion, "work_call", None)
    if callable(remote):
        return dict(remote(op, *args))
    work = getattr(motion, "work", None)
    if work is None:
        from bridge.service.schemas import RequestError

        raise RequestError("unavailable", "work control is not available in this service")
    return dict(work.dispatch(op, *args))


def _forget_paused_work(api: Any) -> dict[str, Any] | None:
    """Clear the work a quick raise paused (``hitch/return`` then only goes back); what it was, or None."""
    implements = getattr(api, "implements", None)
    clear = getattr(implements, "clear_paused_work", None)
    return clear() if callable(clear) else None


def work_handlers(api: Any) -> dict[str, Callable[[Any], dict[str, Any]]]:
    """The ``work/…`` keys for ``api`` (a :class:`~bridge.service.api.ServiceAPI`): settings per
    selected implement in the store, the session calls to the controller's work control (in the
    service's threads: ``motion.work``; in the core process: ``motion.work_call``)."""

    def call(op: str, *args: Any) -> dict[str, Any]:
        return call_work(api.motion, op, *args)

    def stored(implement: str) -> WorkSettings:
        data = api.store.get_work_settings(implement)
        if data is None:
            return WorkSettings()
        try:
            return settings_from_json(data)
        except WorkSettingsError:
            return WorkSettings()  # a stored row an older program wrote: the defaults

    def settings(r: Any) -> dict[str, Any]:
        implement = api.implement
        # null keeps a setting (the schema allows it for every field; "mode": null was refused "got None"),
        # except slip_limit, where null switches slip limiting off
        given = {k: getattr(r, k) for k in r.model_fields_set if getattr(r, k) is not None or k == "slip_limit"}
        current = stored(implement)
        out: dict[str, Any] = {"implement": implement}
        if given:
            new = settings_from_json(given, current)  # WorkSettingsError (bad_request) names field and range
            user = getattr(api._caller, "user", None)
            api.store.save_work_settings(implement, settings_to_json(new), owner=user)
            current = new
            out["saved"] = True
            status = call("configure", settings_to_json(new))
        else:
            status = call("status")
        return {**out, "settings": settings_to_json(current), "status": status}

    def start(r: Any) -> dict[str, Any]:
        s = stored(api.implement)
        if s.mode != "position" and api.implement in (None, DEFAULT_IMPLEMENT):
            from bridge.service.schemas import RequestError

            raise RequestError(  # the soil-engaging modes lower the hitch by what an implement pulls: which one?
                "not_found",
                f"work/start: {s.mode} mode needs the implement in the soil: no implement is selected (select one "
                "first: hitch implement select NAME, key implements/select; position mode works without one)",
            )
        deadline, issued = api._timing(r.deadline_ms)
        reply = {**call("start", settings_to_json(s), r.z, deadline, issued), "implement": api.implement}
        _forget_paused_work(api)  # this session replaces the work a quick raise paused
        return reply

    def stop(_r: Any) -> dict[str, Any]:
        try:
            return call("stop")  # brakes: no deadline
        except MotionError as exc:
            if exc.code != "not_found":  # busy, a core that is closing …: the pause is kept (a review)
                raise
            paused = _forget_paused_work(api)
            if paused is None:
                raise
            # at the headland after a quick raise: no session runs, the return would have started one
            return {"stopping": False, "work_paused_cleared": paused, "work": call("status")}

    def resume(r: Any) -> dict[str, Any]:
        deadline, issued = api._timing(r.deadline_ms)
        return call("resume", deadline, issued)

    return {
        "work/settings": settings,
        "work/start": start,
        "work/stop": stop,
        "work/resume": resume,
    }
