"""The service API: the transport-independent request handler.

:meth:`ServiceAPI.handle` ``(key, payload_bytes, user) -> (ok, reply)`` is the one entry point:
the Zenoh queryables call it (``key`` relative to the prefix, e.g. ``"goto"``), and so does the
operator terminal's HTTP/WebSocket front end (:mod:`bridge.web`). ``ok`` True → ``reply`` is the
answer; False → ``reply`` is ``{"error": code, "message": sentence}`` naming the field and the
limit. It never raises and never returns NaN: every payload goes through
:func:`~bridge.service.schemas.parse_request` first (size, JSON, strict schema → ``bad_request``).

Error codes: ``bad_request`` (payload), ``unknown_key``, ``forbidden`` (access policy),
``mode`` (the mode forbids it), ``busy`` (precedence: stop / jog in progress), ``ecu`` (link
not ready or faulted), ``unreachable`` (outside the workspace or limits), ``refused``
(stability guard), ``ik_failed``, ``not_found``, ``invalid`` (a maneuver that does not
validate), ``store``, ``internal``.

Access: with Zenoh the access-control list of the session enforces who may use the motion keys
(``user`` is None: already authorised). A front end that knows its user passes it, and the
handler applies the same :class:`~bridge.service.security.AccessPolicy` roles (operators:
everything; viewers: :data:`~bridge.service.security.VIEWER_QUERIES`; anyone else: nothing).

Replies are the ``to_json()`` of the values the motion controller and the store return
(:mod:`bridge.service.motion.types`, :mod:`bridge.service.store`); the short confirmations
(``saved``, ``deleted``, ``stopped``, ``mode``) are built here.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from typing import Any

from bridge.service.maneuvers.language import PlanningContext, validate
from bridge.service.motion.controller import MotionController
from bridge.service.motion.types import MODES, ManeuverAccepted, MotionError, PlanPreview, pose_dict
from bridge.service.schemas import (
    API_KEYS,
    REQUESTS,
    Empty,
    JogRequest,
    ManeuverSave,
    ModeRequest,
    NameRequest,
    PlanRequest,
    PoseRequest,
    PresetGo,
    PresetSave,
    RequestError,
    ScriptRequest,
    parse_request,
)
from bridge.service.security import MOTION_KEYS, AccessPolicy
from bridge.service.store import DEFAULT_IMPLEMENT, HitchStore, StoreError
from planner.ik_qp.hitch_ik import IKSolver
from planner.ik_qp.result import Target
from planner.limits.guard import GuardRefusal
from planner.trajectory import MotionState, PlanError

__all__ = ["ServiceAPI", "API_KEYS"]

#: the fields of an IK result the ``ik`` reply carries (in this order)
_IK_REPLY_FIELDS = ("status", "actuators", "pose", "active", "residual", "solve_time_s")


class ServiceAPI:
    """Request handling on top of a motion controller, an IK solver and a store.

    Args:
        motion: the :class:`~bridge.service.motion.controller.MotionController`.
        ik: a :class:`planner.ik_qp.hitch_ik.IKSolver` on its own model (used under a lock).
        store: a :class:`~bridge.service.store.HitchStore`.
        info: the static part of the ``config`` reply (profile, limits, rates …).
        implement: the implement the presets belong to (None: the store's default).
        policy: roles applied when a caller passes ``user``.
    """

    def __init__(
        self,
        motion: MotionController,
        ik: IKSolver,
        store: HitchStore,
        info: Mapping[str, Any],
        *,
        implement: str | None = None,
        policy: AccessPolicy | None = None,
    ):
        self.motion, self.ik, self.store = motion, ik, store
        self.info = dict(info)
        self.implement = implement or DEFAULT_IMPLEMENT
        self.policy = policy
        self._ik_lock = threading.Lock()
        self._handlers: Mapping[str, Callable[[Any], dict]] = {
            "ik": self._ik,
            "plan": self._plan,
            "goto": self._goto,
            "jog": self._jog,
            "stop": self._stop,
            "mode": self._mode,
            "config": self._config,
            "presets/list": self._presets_list,
            "presets/save": self._presets_save,
            "presets/go": self._presets_go,
            "presets/delete": self._presets_delete,
            "maneuvers/validate": self._maneuvers_validate,
            "maneuvers/save": self._maneuvers_save,
            "maneuvers/list": self._maneuvers_list,
            "maneuvers/run": self._maneuvers_run,
            "maneuvers/delete": self._maneuvers_delete,
        }
        self.counts = {"ok": 0, "error": 0}

    def handle(
        self, key: str, payload: bytes | bytearray | memoryview | str | None, user: str | None = None
    ) -> tuple[bool, dict[str, Any]]:
        """Serve one request; never raises. ``key`` relative to the prefix (``"goto"``)."""
        try:
            self._authorise(key, user)
            req = parse_request(key, payload)
            reply = self._handlers[key](req)
        except RequestError as exc:
            return self._err(exc.code, str(exc))
        except MotionError as exc:
            return self._err(exc.code, f"{key}: {exc}")
        except GuardRefusal as exc:
            return self._err("refused", f"{key}: {exc}")
        except PlanError as exc:
            return self._err("unreachable", f"{key}: {exc}")
        except StoreError as exc:
            return self._err("store", f"{key}: {exc}")
        except ValueError as exc:
            return self._err("bad_request", f"{key}: {exc}")
        except Exception as exc:  # noqa: BLE001 — a bug must not kill the service or leave a query open
            return self._err("internal", f"{key}: internal error {type(exc).__name__}: {str(exc)[:200]}")
        self.counts["ok"] += 1
        return True, reply

    def _err(self, code: str, message: str) -> tuple[bool, dict[str, Any]]:
        self.counts["error"] += 1
        return False, {"error": code, "message": message}

    def _authorise(self, key: str, user: str | None) -> None:
        if user is None or self.policy is None or key not in REQUESTS:
            return
        p = self.policy
        if user in p.operators or (user in p.viewers and key in p.viewer_queries and key not in MOTION_KEYS):
            return
        role = "viewer" if user in p.viewers else "unknown user"
        raise RequestError(
            "forbidden",
            f"{key}: user {user!r} ({role}) may not use {key!r}; "
            f"motion keys ({', '.join(MOTION_KEYS)}) need an operator",
        )

    # ------------------------------------------------------------------ no motion
    def _ik(self, r: PoseRequest) -> dict:
        target = Target(r.x, r.z, r.roll, r.pitch)
        with self._ik_lock:
            res = self.ik.solve(target)
        if res.status == "failed":
            raise RequestError("ik_failed", f"ik: no solution ({res.reason})")
        out = res.to_json()
        return {k: out[k] for k in _IK_REPLY_FIELDS}

    def _plan(self, r: PlanRequest) -> dict:
        try:
            preview = PlanPreview.planned(self.motion.preview(r.goal.as_dict(), r.speed_scale))
        except PlanError as exc:  # the planner's or the guard's (GuardRefusal) refusal
            preview = PlanPreview.refusal(exc)
        return preview.to_json()

    def _config(self, _r: Empty) -> dict:
        return {**self.info, "mode": self.motion.mode, "implement": self.info.get("implement")}

    # ------------------------------------------------------------------ motion
    def _goto(self, r: PlanRequest) -> dict:
        return self.motion.goto(r.goal.as_dict(), r.speed_scale).to_json()

    def _jog(self, r: JogRequest) -> dict:
        rates = {"vx": r.vx, "vz": r.vz, "vroll": r.vroll, "vpitch": r.vpitch}
        return self.motion.jog(rates, r.ttl_ms / 1000.0).to_json()

    def _stop(self, _r: Empty) -> dict:
        return {"stopped": True, "motion_id": self.motion.stop()}

    def _mode(self, r: ModeRequest) -> dict:
        if r.mode is None:
            return {"mode": self.motion.mode, "modes": list(MODES)}
        return {"mode": self.motion.set_mode(r.mode), "modes": list(MODES)}

    # ------------------------------------------------------------------ presets
    def _presets_list(self, _r: Empty) -> dict:
        return {"presets": [p.to_json() for p in self.store.list_presets(self.implement)], "implement": self.implement}

    def _presets_save(self, r: PresetSave) -> dict:
        current = self.motion.current_state().position
        pose = self.motion.planner.goal_vector(current, r.pose.as_dict() if r.pose is not None else {})
        self.motion.planner.check_in_workspace(pose, "pose")
        p = self.store.save_preset(r.name, pose_dict(pose), implement=self.implement, speed_scale=r.speed_scale)
        return {"saved": p.name, "pose": dict(p.pose), "implement": p.implement}

    def _presets_go(self, r: PresetGo) -> dict:
        p = self.store.get_preset(r.name, implement=self.implement)
        if p is None:
            raise RequestError("not_found", f"presets/go: no preset {r.name!r} for implement {self.implement!r}")
        scale = r.speed_scale or p.speed_scale or 1.0
        return {**self.motion.goto(dict(p.pose), scale, kind="preset", label=p.name).to_json(), "preset": p.name}

    def _presets_delete(self, r: NameRequest) -> dict:
        if not self.store.delete_preset(r.name, implement=self.implement):
            raise RequestError("not_found", f"presets/delete: no preset {r.name!r} for implement {self.implement!r}")
        return {"deleted": r.name}

    # ------------------------------------------------------------------ maneuvers
    def _context(self) -> PlanningContext:
        start = MotionState.at_rest(self.motion.current_state().position)
        return PlanningContext(
            start, self.motion.plan_step, lambda n: self.store.get_preset(n, implement=self.implement)
        )

    def _maneuvers_validate(self, r: ScriptRequest) -> dict:
        return validate(r.script, self._context()).to_json()

    def _maneuvers_save(self, r: ManeuverSave) -> dict:
        stored = self.store.save_maneuver(r.name, r.script)  # ManeuverError (a HitchInputError) lists the problems
        return {"saved": stored.name, "steps": len(stored.parsed.steps)}

    def _maneuvers_list(self, _r: Empty) -> dict:
        return {"maneuvers": [m.to_json(script=False) for m in self.store.list_maneuvers()]}

    def _maneuvers_run(self, r: NameRequest) -> dict:
        m = self.store.get_maneuver(r.name)
        if m is None:
            raise RequestError("not_found", f"maneuvers/run: no maneuver {r.name!r}")
        res = validate(m.parsed, self._context())
        if not res.ok:
            first = res.errors[0]
            raise RequestError(
                "invalid", f"maneuvers/run: {r.name!r} does not validate from the current pose: {first.sentence()}"
            )
        mid = self.motion.run_maneuver(res, r.name)
        return ManeuverAccepted(mid, res.duration, len(res.steps), r.name).to_json()

    def _maneuvers_delete(self, r: NameRequest) -> dict:
        if not self.store.delete_maneuver(r.name):
            raise RequestError("not_found", f"maneuvers/delete: no maneuver {r.name!r}")
        return {"deleted": r.name}
