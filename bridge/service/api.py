"""The service API: the transport-independent request handler.

:meth:`ServiceAPI.handle` ``(key, payload_bytes, user) -> (ok, reply)`` is the one entry point:
the Zenoh queryables call it (``key`` relative to the prefix, e.g. ``"goto"``), and so does the
operator terminal's HTTP/WebSocket front end (:mod:`bridge.web`). ``ok`` True → ``reply`` is the
answer; False → ``reply`` is ``{"error": code, "message": sentence}`` naming the field and the
limit. It never raises and never returns NaN: every payload goes through
:func:`~bridge.service.schemas.parse_request` first (size, JSON, strict schema → ``bad_request``).

Error codes: ``bad_request`` (payload), ``unknown_key``, ``forbidden`` (access policy),
``mode`` (the mode forbids it), ``busy`` (precedence: stop / jog in progress; a motion request
that cannot start by its deadline (field deadline_ms) or that a later stop cancelled; too many expensive
requests of one user in flight, :data:`EXPENSIVE_KEYS`), ``ecu`` (link not ready, or a fault held:
docs/faults.md), ``unavailable`` (the sim/fault key without a simulated ECU), ``unreachable``
(outside the workspace or limits), ``refused`` (stability guard), ``ik_failed``, ``not_found``,
``invalid`` (a maneuver that does not validate), ``store``, ``internal``.

Access: with Zenoh the access-control list of the session enforces who may use the motion keys
(``user`` is None: already authorised). A front end that knows its user passes it, and the
handler applies the same :class:`~bridge.service.security.AccessPolicy` roles (operators:
everything; viewers: :data:`~bridge.service.security.VIEWER_QUERIES`; anyone else: nothing).

Replies are the ``to_json()`` of the values the motion controller and the store return
(:mod:`bridge.service.motion.types`, :mod:`bridge.service.store`); the short confirmations
(``saved``, ``deleted``, ``stopped``, ``mode``) are built here.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from bridge.service.event_ring import EventRing
from bridge.service.gnss import lines_handlers
from bridge.service.implements import ImplementService, implement_handlers
from bridge.service.maneuvers.language import (
    ManeuverError,
    ManeuverScript,
    StepError,
    ValidationResult,
    goto_workspace_errors,
    parse_maneuver,
)
from bridge.service.maneuvers.recorder import ManeuverRecorder, maneuvers_using_preset, recorder_for
from bridge.service.maneuvers.steps import WaitForStep, step_words
from bridge.service.motion.controller import MotionController
from bridge.service.motion.types import MODES, ManeuverAccepted, MotionError, pose_dict
from bridge.service.planning import InProcessPlanning, Planning
from bridge.service.schemas import (
    API_KEYS,
    REQUESTS,
    Empty,
    EventsRecent,
    GotoRequest,
    JogRequest,
    ManeuverRun,
    ManeuverSave,
    ModeRequest,
    MotionControl,
    NameRequest,
    PlanRequest,
    PoseRequest,
    PresetDelete,
    PresetGo,
    PresetSave,
    RecordStop,
    RequestError,
    ScriptRequest,
    SimFaultRequest,
    TrackSetpoint,
    TrackStart,
    TrackStop,
    check_pose_in_workspace,
    parse_request,
    setpoint_session,
)
from bridge.service.security import AccessPolicy
from bridge.service.store import DEFAULT_IMPLEMENT, HitchStore, ManeuverExists, PresetExists, StoreError
from bridge.service.work import work_handlers
from bridge.service.workers import PresetPose, WorkerError, referenced_presets
from planner.errors import HitchInputError
from planner.ik_qp.hitch_ik import IKSolver
from planner.limits.guard import GuardRefusal
from planner.trajectory import MotionState, PlanError

__all__ = ["ServiceAPI", "API_KEYS", "EXPENSIVE_KEYS", "MAX_IN_FLIGHT_PER_USER"]

#: internal errors (a request that raised what no handler expected) are logged here with their traceback
log = logging.getLogger("hitch.service.api")

#: requests whose cost is not bounded by the control loop (planning, parsing and validating a maneuver script):
#: admission-controlled. A save parses its script as validate does (up to 64 KiB of YAML, tens of ms), on the
#: service's threads: six clients flooding saves held presets/list 4.6 s (a trial)
EXPENSIVE_KEYS = frozenset({"plan", "maneuvers/validate", "maneuvers/save"})
#: expensive requests one user may have running at a time; more are refused with ``busy`` at once
MAX_IN_FLIGHT_PER_USER = 2

#: the fields of an IK result the ``ik`` reply carries (in this order)
_IK_REPLY_FIELDS = ("status", "actuators", "pose", "active", "residual", "solve_time_s")


class ServiceAPI:
    """Request handling on top of a motion controller, an IK solver and a store.

    Args:
        motion: the :class:`~bridge.service.motion.controller.MotionController`.
        ik: a :class:`planner.ik_qp.hitch_ik.IKSolver` on its own model (used under a lock) for the
            in-process planning (when ``planning`` is None).
        store: a :class:`~bridge.service.store.HitchStore`.
        info: the static part of the ``config`` reply (profile, limits, rates …).
        implement: the implement named at start-up (None: none; the persisted selection may win over it:
            :class:`~bridge.service.implements.ImplementService`).
        implement_source: where ``implement`` came from: "flag" (it wins over the persisted selection) or "file".
        policy: roles applied when a caller passes ``user``.
        planning: where ``plan``, validation and ``ik`` run (:class:`~bridge.service.planning.Planning`;
            default: :class:`~bridge.service.planning.InProcessPlanning` on ``motion`` and ``ik``).
    """

    #: implements and the quick raise / return (set while the handlers are built: bridge.service.implements)
    implements: ImplementService

    #: every key :meth:`handle` serves (the operator terminal answers a GET of any other 'unknown key')
    api_keys: tuple[str, ...] = tuple(API_KEYS)

    def __init__(
        self,
        motion: MotionController,
        ik: IKSolver | None,
        store: HitchStore,
        info: Mapping[str, Any],
        *,
        implement: str | None = None,
        implement_source: str = "file",
        policy: AccessPolicy | None = None,
        sim_fault: Callable[[Mapping[str, Any]], Any] | None = None,
        planning: Planning | None = None,
    ):
        self.motion, self.store = motion, store
        self.planning: Planning = planning if planning is not None else InProcessPlanning(motion, ik)
        self.sim_fault = sim_fault  # the simulated ECU's fault injection (None: a real ECU, or none)
        self._in_flight: dict[str, int] = {}  # expensive requests running, per user
        self._in_flight_lock = threading.Lock()
        self._record_lock = threading.Lock()  # maneuvers/record/start|stop
        self.info = dict(info)
        self.implement = implement or DEFAULT_IMPLEMENT
        #: where the start-up's ``implement`` came from ("flag": it wins over the persisted selection; "file": the
        #: persisted selection wins over it; ServiceConfig.implement_source, bridge.service.implements)
        self.implement_source = implement_source
        self.policy = policy
        self._caller = threading.local()  # .user: the user of the request this thread is serving (store owner)
        self._handlers: Mapping[str, Callable[[Any], dict]] = {
            "ik": self._ik,
            "plan": self._plan,
            "goto": self._goto,
            "jog": self._jog,
            "stop": self._stop,
            "mode": self._mode,
            "config": self._config,
            "events/recent": self._events_recent,
            "presets/list": self._presets_list,
            "presets/save": self._presets_save,
            "presets/go": self._presets_go,
            "presets/delete": self._presets_delete,
            "maneuvers/validate": self._maneuvers_validate,
            "maneuvers/save": self._maneuvers_save,
            "maneuvers/list": self._maneuvers_list,
            "maneuvers/run": self._maneuvers_run,
            "maneuvers/delete": self._maneuvers_delete,
            "faults/ack": self._faults_ack,
            "sim/fault": self._sim_fault,
            "track/start": self._track_start,
            "track/setpoint": self._track_setpoint,
            "track/stop": self._track_stop,
            "maneuvers/pause": lambda _r: self.motion.maneuver_control("pause"),  # brakes: no deadline
            "maneuvers/resume": lambda r: self._maneuver_control("resume", r),
            "maneuvers/skip": lambda r: self._maneuver_control("skip", r),
            "maneuvers/record/start": self._record_start,
            "maneuvers/record/stop": self._record_stop,
            **lines_handlers(self),  # lines/save|list|delete: the core's tracker and the store (bridge.service.gnss)
            **implement_handlers(self),  # implements/… and hitch/raise|return (docs/implements.md)
            **work_handlers(self),  # work/settings|start|stop|resume (bridge.service.work, docs/soil.md)
        }
        self.recorder: ManeuverRecorder | None = None  # teach-in (maneuvers/record/start)
        #: the last events the service heard, for ``events/recent`` (its server feeds :meth:`EventRing.take`)
        self.events = EventRing()
        self.counts = {"ok": 0, "error": 0}
        #: optional ``on_request(key, user, payload, ok, reply)`` after every request (the black box)
        self.on_request: Callable[..., None] | None = None

    def handle(
        self,
        key: str,
        payload: bytes | bytearray | memoryview | str | None,
        user: str | None = None,
        *,
        received: float | None = None,
    ) -> tuple[bool, dict[str, Any]]:
        """Serve one request; never raises. ``key`` relative to the prefix (``"goto"``).

        ``received``: ``time.monotonic()`` when the request arrived (default: now). A motion
        request's ``deadline_ms`` counts from then, and a stop sent after it cancels it, so time
        spent waiting in a queue is not forgiven."""
        self._caller.received = time.monotonic() if received is None else float(received)
        ok, reply = self._handle(key, payload, user)
        hook = self.on_request
        if hook is not None:
            try:
                hook(key, user, payload, ok, reply)
            except Exception:  # noqa: BLE001 — a recorder's bug must not fail the request
                pass
        return ok, reply

    def _handle(
        self, key: str, payload: bytes | bytearray | memoryview | str | None, user: str | None
    ) -> tuple[bool, dict[str, Any]]:
        admitted: str | None = None
        try:
            self._authorise(key, user)
            self._caller.user = user
            if key in EXPENSIVE_KEYS:
                admitted = self._admit(key, user)
            req = parse_request(key, payload, workspace=(self.info.get("limits") or {}).get("workspace"))
            reply = self._handlers[key](req)
        except RequestError as exc:
            if key == "track/setpoint":  # counted against its session like any rejection (a put's, too)
                try:
                    self.motion.track_setpoint_refused(setpoint_session(payload), str(exc))
                except Exception:  # noqa: BLE001 — a core that cannot count it changes nothing of the reply
                    pass
            return self._err(exc.code, _named(key, exc))
        except MotionError as exc:
            return self._err(exc.code, _named(key, exc))
        except GuardRefusal as exc:
            return self._err("refused", _named(key, exc))
        except PlanError as exc:
            return self._err("unreachable", _named(key, exc))
        except StoreError as exc:  # the database or a per-user limit: "store"; a value the store refuses: bad_request
            code = "store" if exc.field in _STORE_FAULT_FIELDS or exc.field.startswith("max_") else "bad_request"
            return self._err(code, _named(key, exc))
        except WorkerError as exc:
            return self._err(exc.code, _named(key, exc))
        except ValueError as exc:
            return self._err("bad_request", _named(key, exc))
        except Exception as exc:  # noqa: BLE001 — a bug must not kill the service or leave a query open
            # the reply names the exception only: its traceback goes to the log (stderr) for the developer
            log.exception("service API: internal error serving %r for user %r", key, user)
            return self._err("internal", f"{key}: internal error {type(exc).__name__}: {str(exc)[:200]}")
        finally:
            if admitted is not None:
                with self._in_flight_lock:
                    left = self._in_flight[admitted] - 1
                    if left > 0:
                        self._in_flight[admitted] = left
                    else:  # no entry per name ever seen: the table stays as small as the requests running
                        del self._in_flight[admitted]
        self.counts["ok"] += 1
        return True, reply

    def _err(self, code: str, message: str) -> tuple[bool, dict[str, Any]]:
        self.counts["error"] += 1
        return False, {"error": code, "message": message}

    def _admit(self, key: str, user: str | None) -> str:
        """Admission control: at most :data:`MAX_IN_FLIGHT_PER_USER` expensive requests (plan, maneuver
        validate and save) of one user at a time; beyond that ``busy`` at once. Returns the user's slot."""
        who = user or "-"
        with self._in_flight_lock:
            n = self._in_flight.get(who, 0)
            if n >= MAX_IN_FLIGHT_PER_USER:
                whose = (
                    "this user"
                    if user
                    # every client without a user name shares one allowance (a fleet trial read "of this client"
                    # while its own client had none running: another anonymous client flooded)
                    else "clients without a user name (they share one allowance; a user's own keys have their own: "
                    "docs/security.md)"
                )
                raise RequestError(
                    "busy",
                    f"{key}: {n} expensive requests ({', '.join(sorted(EXPENSIVE_KEYS))}) of {whose} are running "
                    f"(allowed: {MAX_IN_FLIGHT_PER_USER} at a time); send it again when one has been answered",
                )
            self._in_flight[who] = n + 1
        return who

    def _timing(self, deadline_ms: int) -> tuple[float, float]:
        """(deadline on the motion clock [s], arrival ``time.monotonic()``) of this thread's request."""
        received = float(getattr(self._caller, "received", None) or time.monotonic())
        waited = max(0.0, time.monotonic() - received)
        return self.motion.clock() + deadline_ms / 1000.0 - waited, received

    def _authorise(self, key: str, user: str | None) -> None:
        if user is None or self.policy is None or key not in REQUESTS:
            return
        if not self.policy.permits(user, key):  # operator keys (motion and writes) need an operator
            raise RequestError("forbidden", self.policy.refusal(user, key))

    # ------------------------------------------------------------------ no motion
    def _ik(self, r: PoseRequest) -> dict:
        out = self.planning.ik((r.x, r.z, r.roll, r.pitch))  # ik_failed: "ik: no solution (…)"
        return {k: out[k] for k in _IK_REPLY_FIELDS}

    def _plan(self, r: PlanRequest) -> dict:
        start = self.motion.preview_start()
        return self.planning.preview(start, r.goal.as_dict(), r.speed_scale)

    def _events_recent(self, r: EventsRecent) -> dict:
        """The events after ``r.after`` the service still keeps (:class:`~bridge.service.event_ring.EventRing`), with
        this run's ``instance``: numbers from another run mean nothing here."""
        return {**self.events.after(r.after, r.limit), "instance": self.info.get("instance")}

    def _config(self, _r: Empty) -> dict:
        return {**self.info, "mode": self.motion.mode, "implement": self.info.get("implement")}

    # ------------------------------------------------------------------ motion
    def _goto(self, r: GotoRequest) -> dict:
        deadline, issued = self._timing(r.deadline_ms)
        reply = self.motion.goto(r.goal.as_dict(), r.speed_scale, deadline=deadline, issued=issued).to_json()
        if (rec := self.recorder) is not None:  # teach-in (read once: a record/stop may run meanwhile)
            rec.on_goto(r.goal.as_dict(), r.speed_scale, float(reply.get("duration", 0.0)))
        return reply

    def _jog(self, r: JogRequest) -> dict:
        deadline, issued = self._timing(r.deadline_ms)  # late, or sent before the latest stop: never run
        rates = {"vx": r.vx, "vz": r.vz, "vroll": r.vroll, "vpitch": r.vpitch}
        holder = getattr(self._caller, "user", None)  # one jog at a time: another user's is refused while live
        reply = self.motion.jog(rates, r.ttl_ms / 1000.0, deadline=deadline, issued=issued, holder=holder).to_json()
        if (rec := self.recorder) is not None:  # teach-in (read once: a record/stop may run meanwhile)
            rec.on_jog(r.ttl_ms / 1000.0)
        return reply

    def _stop(self, _r: object) -> dict:  # whatever came with it: a stop stops
        taken = time.time()  # Unix time [s] the stop was taken (the core's own answer carries the same)
        return {"stopped": True, **self.motion.stop_report(), "t": taken}

    def _track_start(self, r: TrackStart) -> dict:
        deadline, issued = self._timing(r.deadline_ms)
        return self.motion.track_start(
            r.frame, tuple(r.dof), r.ttl_ms / 1000.0, deadline=deadline, issued=issued, replace=r.replace
        ).to_json()

    def _maneuver_control(self, action: str, r: MotionControl) -> dict:
        """``maneuvers/resume`` / ``maneuvers/skip``: they start the next motion, so they keep a deadline."""
        deadline, issued = self._timing(r.deadline_ms)
        return self.motion.maneuver_control(action, deadline=deadline, issued=issued)

    def _track_setpoint(self, r: TrackSetpoint) -> dict:
        velocity = None if r.velocity is None else r.velocity.as_dict()
        return self.motion.track_setpoint(r.session, r.seq, r.pose.as_dict(), velocity)

    def _track_stop(self, r: TrackStop) -> dict:
        return self.motion.track_stop(r.session, r.last_seq)

    def _faults_ack(self, _r: Empty) -> dict:
        return self.motion.ack_faults().to_json()

    def _sim_fault(self, r: SimFaultRequest) -> dict:
        if self.sim_fault is None:
            raise RequestError(
                "unavailable",
                "sim/fault: no simulated ECU runs in this service (a real ECU is connected, or the twin runs "
                "in another process); fault injection is only for the twin",
            )
        applied = self.sim_fault(r.model_dump())
        to_json = getattr(applied, "to_json", None)
        return {"applied": to_json() if callable(to_json) else r.model_dump()}

    def _mode(self, r: ModeRequest) -> dict:
        if r.mode is None:
            return {"mode": self.motion.mode, "modes": list(MODES)}
        return {"mode": self.motion.set_mode(r.mode), "modes": list(MODES)}

    # ------------------------------------------------------------------ presets
    def _presets_list(self, _r: Empty) -> dict:
        return {"presets": [p.to_json() for p in self.store.list_presets(self.implement)], "implement": self.implement}

    def _presets_save(self, r: PresetSave) -> dict:
        # the implement's pose (the mechanism less the profile's lag): presets/go aims the mechanism back here
        current = self.motion.planner.implement_pose(self.motion.current_state().position)
        pose = self.motion.planner.goal_vector(current, r.pose.as_dict() if r.pose is not None else {})
        self.motion.planner.check_in_workspace(pose, "pose")
        imp = self.implements.current() if getattr(self, "implements", None) is not None else None
        upper = None if imp is None else imp.limits.upper_height_m
        if imp is not None and upper is not None and pose[1] > upper + 1e-9:  # a preset that could never run
            raise RequestError(
                "unreachable",
                f"presets/save: pose.z = {pose[1]:.4f} m is above the upper height of the implement {imp.name!r}, "
                f"{upper:g} m (upper_height_m): presets/go would refuse it",
            )
        replaced = r.replace and self.store.get_preset(r.name, implement=self.implement) is not None
        try:
            p = self.store.save_preset(
                r.name,
                pose_dict(pose),
                implement=self.implement,
                speed_scale=r.speed_scale,
                owner=getattr(self._caller, "user", None),
                replace=r.replace,
            )
        except PresetExists as exc:  # not replaced unasked (a fleet trial: a save overwrote a preset silently)
            was = ", ".join(f"{k} {v:.4g}" for k, v in exc.pose.items())
            raise RequestError(
                "in_use",
                f"presets/save: implement {self.implement!r} has a preset {exc.name!r} already ({was} [m, rad]); send "
                f'it with "replace": true to replace it (CLI: hitch preset save {exc.name} --replace), or save it '
                "under another name",
            ) from None
        out: dict[str, Any] = {"saved": p.name, "pose": dict(p.pose), "implement": p.implement}
        if replaced:
            out["replaced"] = True
        if p.name == "headland" and imp is not None and imp.headland is not None:  # implements.HEADLAND_PRESET
            # the implement's own pose comes first: a taught "headland" that a raise never used (a newcomer's trial)
            out["note"] = (
                f"implement {imp.name!r} has a headland pose of its own (z {imp.headland['z']:.4f} m): hitch/raise "
                "goes there, not to this preset; redefine the implement without 'headland' to raise to this one"
            )
        return out

    def _presets_go(self, r: PresetGo) -> dict:
        p = self.store.get_preset(r.name, implement=self.implement)
        if p is None:
            raise RequestError("not_found", f"presets/go: no preset {r.name!r} for implement {self.implement!r}")
        workspace = (self.info.get("limits") or {}).get("workspace")
        check_pose_in_workspace(p.pose, workspace, key="presets/go", what="pose")  # names the range of every DOF
        scale = r.speed_scale or p.speed_scale or 1.0
        deadline, issued = self._timing(r.deadline_ms)
        acc = self.motion.goto(dict(p.pose), scale, kind="preset", label=p.name, deadline=deadline, issued=issued)
        if (rec := self.recorder) is not None:  # teach-in (read once: a record/stop may run meanwhile)
            rec.on_preset(p.name, r.speed_scale, float(acc.to_json().get("duration", 0.0)))
        return {**acc.to_json(), "preset": p.name}

    def _presets_delete(self, r: PresetDelete) -> dict:
        users = maneuvers_using_preset(self.store, r.name)
        if users and not r.force:
            raise RequestError(
                "in_use",
                f"presets/delete: preset {r.name!r} is used by the saved maneuver(s) {', '.join(users)}; "
                "send force: true (`hitch preset delete NAME --force`) to delete it anyway "
                "(those maneuvers then fail to validate)",
            )
        if not self.store.delete_preset(r.name, implement=self.implement):
            raise RequestError("not_found", f"presets/delete: no preset {r.name!r} for implement {self.implement!r}")
        out: dict[str, Any] = {"deleted": r.name}
        if users:
            out.update(warning=f"preset {r.name!r} was used by {', '.join(users)}", maneuvers=users)
        return out

    # ------------------------------------------------------------------ teach-in
    def _record_start(self, _r: Empty) -> dict:
        with self._record_lock:  # two starts at once: one recording, the other busy
            if self.recorder is not None:
                raise RequestError("busy", "maneuvers/record/start: a recording runs already; record/stop it first")
            self.recorder = recorder_for(self.motion)
        return {"recording": True}

    def _record_stop(self, r: RecordStop) -> dict:
        with self._record_lock:
            rec, self.recorder = self.recorder, None
        if rec is None:
            raise RequestError("not_found", "maneuvers/record/stop: no recording runs (maneuvers/record/start)")
        script = rec.stop(r.name)
        out: dict[str, Any] = {"script": script, "steps": len(rec.steps)}
        if r.name is not None:  # saved as the API says (it was only named: a new user's report)
            try:
                out.update(self._save_maneuver(r.name, script, r.replace))
            except ManeuverExists as exc:  # not replaced unasked (a 6-step maneuver became a 1-step recording)
                with self._record_lock:  # the recording goes on: stop it again with another name, or replace
                    kept = self.recorder is None
                    if kept:
                        self.recorder = rec
                if kept:
                    raise RequestError(
                        "in_use",
                        f"maneuvers/record/stop: {_exists(exc)}; nothing was saved and the recording goes on "
                        f"({len(rec.steps)} step(s) so far): record/stop it with another name, or with "
                        f'"replace": true (CLI: hitch maneuver record stop --save {exc.name} --replace) to replace '
                        f"{exc.name!r}",
                    ) from None
                out["not_saved"] = f"{_exists(exc)} (a new recording runs: this script is not kept by the service)"
            except HitchInputError as exc:  # the script is returned all the same: nothing recorded is lost
                out["not_saved"] = str(exc)
            out["steps"] = len(rec.steps)
        return out

    # ------------------------------------------------------------------ maneuvers
    def _validated(self, script: str | ManeuverScript) -> ValidationResult:
        """Validation from the current pose (parsed here, planned by :attr:`planning`); never raises on a bad script."""
        if not isinstance(script, ManeuverScript):
            try:
                script = parse_maneuver(script)
            except ManeuverError as exc:
                return ValidationResult(False, 0.0, exc.errors)
        presets: dict[str, PresetPose] = {}
        for name in referenced_presets(script):
            p = self.store.get_preset(name, implement=self.implement)
            if p is not None:
                presets[name] = PresetPose(dict(p.pose), p.speed_scale)
        start = MotionState.at_rest(self.motion.current_state().position)
        res = self.planning.validate(script, start, presets)
        # every step's own problems, beside what planning found (it stops at the first step it cannot plan,
        # or at a missing preset: a missing line at step 0 was not said beside a missing preset at step 2):
        # a wait_for line no one saved (the run would abort at that step: it validated, was accepted, and
        # aborted at once with trigger_unavailable: a new user's report), and a goto whose own goal lies
        # outside the workspace (known without planning from the step before)
        lines = {name for name, _ in self.store.list_lines()}
        saved = ", ".join(sorted(lines)) or "none"
        extra = [
            StepError(i, f"wait_for.line: no line {s.line!r} is saved (lines/save; saved: {saved})")
            for i, s in enumerate(script.steps)
            if isinstance(s, WaitForStep) and s.line is not None and s.line not in lines
        ]
        said = {e.step for e in res.errors}
        extra += [
            StepError(e.step, f"goto cannot be planned: {e.message}")
            for e in goto_workspace_errors(script, self.motion.planner)
            if e.step not in said
        ]
        if not extra:
            return res
        errors = sorted([*res.errors, *extra], key=lambda e: -1 if e.step is None else e.step)
        return ValidationResult(False, res.duration if res.ok else 0.0, tuple(errors), res.script)

    def _maneuvers_validate(self, r: ScriptRequest) -> dict:
        return self._validated(r.script).to_json()

    def _maneuvers_save(self, r: ManeuverSave) -> dict:
        """Store a maneuver; a name saved already is refused (``in_use``) unless ``replace`` (a 6-step maneuver
        was silently replaced by a 1-step recording). With ``replace`` the reply says ``replaced: true`` when
        it did replace one."""
        try:
            return self._save_maneuver(r.name, r.script, r.replace)
        except ManeuverExists as exc:
            raise RequestError(
                "in_use",
                f'maneuvers/save: {_exists(exc)}; send it with "replace": true to replace it (CLI: hitch '
                f"maneuver save {exc.name} FILE --replace), or save it under another name",
            ) from None

    def _save_maneuver(self, name: str, script: str, replace: bool) -> dict:
        """Parse, check and store (:class:`ManeuverExists` when ``name`` is saved and not ``replace``)."""
        parsed = parse_maneuver(script)  # ManeuverError (a HitchInputError) lists the problems
        self._check_goto_steps(parsed)
        stored = self.store.save_maneuver(
            name, script, owner=getattr(self._caller, "user", None), parsed=parsed, replace=replace
        )
        out: dict[str, Any] = {"saved": stored.name, "steps": len(stored.parsed.steps)}
        if stored.replaced:
            out["replaced"] = True
        return out

    def _check_goto_steps(self, parsed: ManeuverScript) -> None:
        """A goto step outside the workspace is refused at save, naming the step (:func:`step_words`, as validate and
        the runner name it) and the face with the planner's own words and unit hint, as validate says it and
        presets/save refuses such a pose (it was saved, then every run refused it; a fleet trial)."""
        errors = goto_workspace_errors(parsed, self.motion.planner)
        if errors:
            said = "; ".join(f"{step_words(e.step or 0, 'goto')}: {e.message}" for e in errors)  # each has a step
            raise RequestError(
                "unreachable",
                f"maneuvers/save: {said}; no run could reach {'it' if len(errors) == 1 else 'them'}",
            )

    def _maneuvers_list(self, _r: Empty) -> dict:
        return {"maneuvers": [m.to_json(script=False) for m in self.store.list_maneuvers()]}

    def _maneuvers_run(self, r: ManeuverRun) -> dict:
        m = self.store.get_maneuver(r.name)
        if m is None:
            raise RequestError("not_found", f"maneuvers/run: no maneuver {r.name!r}")
        res = self._validated(m.parsed)
        if not res.ok:
            first = res.errors[0]
            raise RequestError(
                "invalid", f"maneuvers/run: {r.name!r} does not validate from the current pose: {first.sentence()}"
            )
        deadline, issued = self._timing(r.deadline_ms)
        mid = self.motion.run_maneuver(res, r.name, deadline=deadline, issued=issued)
        script_steps = len(res.script.steps) if res.script is not None else len(res.steps)
        out = ManeuverAccepted(mid, res.duration, script_steps, r.name, actions=len(res.steps)).to_json()
        if self.info.get("instance") is not None:  # the run its id belongs to (a restarted service counts from 1)
            out["instance"] = self.info["instance"]
        return out

    def _maneuvers_delete(self, r: NameRequest) -> dict:
        if not self.store.delete_maneuver(r.name):
            raise RequestError("not_found", f"maneuvers/delete: no maneuver {r.name!r}")
        return {"deleted": r.name}


#: StoreError fields that mean the database itself (not a value of the request)
_STORE_FAULT_FIELDS = frozenset({"path", "database", "store", "schema_version"})


def _exists(exc: ManeuverExists) -> str:
    """``a maneuver 'x' is saved already (6 steps)``: what a save without replace would have replaced."""
    steps = "" if exc.steps is None else f" ({exc.steps} step{'' if exc.steps == 1 else 's'})"
    return f"a maneuver {exc.name!r} is saved already{steps}"


def _named(key: str, exc: BaseException) -> str:
    """The error text headed by the request's key, once: ``goto: …``, not ``goto: goto refused: …``
    when the text already begins with the key (the motion controller names the kind of motion)."""
    text = str(exc)
    return text if text.startswith((f"{key} ", f"{key}:")) else f"{key}: {text}"
