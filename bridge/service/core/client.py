"""The service's side of the control core process: starting it, calling it, and a controller proxy.

:class:`CoreProcess` starts ``python -m bridge.service.core.process`` (a fresh interpreter: nothing
of the embedding program is imported twice) on one end of a socket pair, waits for its ``ready``
message and then matches replies to calls by id on a reader thread, so calls from many threads
(the request lanes, the terminal) are in flight at once and none waits for another's answer.
:class:`MotionProxy` offers what :class:`~bridge.service.api.ServiceAPI` uses of a
:class:`~bridge.service.motion.controller.MotionController` on top of it: the same methods, the
same errors (:class:`CoreError` carries the API's code and text), the same clock (the core's
clock is the link runner's node time; on Linux ``time.monotonic()`` is one clock for every
process, so the proxy reads it as ``monotonic() − t0``).

A core that dies ends the service's motion for good: every call then fails with ``unavailable``
and the service's supervisor (:func:`bridge.service.server.serve`) stops the service with the
reason — an old plan is never resumed, and the ECU's watchdog holds the valves at zero without
references.

A thread of its own (``core-keepalive``) sends the core a keep-alive every :data:`KEEPALIVE_S`, whatever the
request threads do: a core that hears nothing from its service for
:data:`~bridge.service.core.process.SERVICE_SILENCE_S` (the service frozen, hung or swapped out: nobody's
``stop`` reaches the core through it) brakes the hitch to rest (``service_lost``).
"""

from __future__ import annotations

import itertools
import json
import multiprocessing.connection
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any

from bridge.service.config import ServiceConfig
from bridge.service.motion.types import MotionError
from bridge.service.security import Credentials
from planner.trajectory import MotionState, TrajectoryPlanner

__all__ = ["CoreError", "CoreProcess", "MotionProxy", "JsonReply", "core_config_json"]

#: how long the core may take to start (models, buses, Zenoh) [s]
START_TIMEOUT_S = 60.0
#: the longest any call waits for its answer unless it says otherwise [s]
CALL_TIMEOUT_S = 10.0
#: period of the service's keep-alive to its core [s]: a core that hears nothing for
#: :data:`~bridge.service.core.process.SERVICE_SILENCE_S` (2 s, 8 periods) brakes the hitch (``service_lost``)
KEEPALIVE_S = 0.25


class CoreError(MotionError):
    """A call the core refused or could not answer; ``code`` is the API's error code."""


class JsonReply:
    """A reply the core sent as JSON-ready data, offered as the controller's value types are (``to_json()``)."""

    def __init__(self, data: Mapping[str, Any]):
        self._data = dict(data)

    def to_json(self) -> dict[str, Any]:
        return dict(self._data)


def core_config_json(cfg: ServiceConfig) -> str:
    """The service's config as the core process reads it back (``ServiceConfig.model_validate_json``): only
    the fields the user set, so the copy knows which were set, as the service's own does (a full dump marked
    every field set: the field twin then took ``sim_ground_speed``'s default 1.5 m/s for the user's speed and
    drove at it instead of the field's own 8 km/h, a review)."""
    return cfg.model_dump_json(exclude_unset=True)


class CoreProcess:
    """The control core's process (module docstring). ``start()``, :meth:`call`, ``close()``.

    Args:
        config: the service's settings (the core builds its parts from them).
        on_note: called (on the reader thread) with each note the core sends about what it answered on
            its own (``{"request": "stop", "ok", "reply", "payload"}``).
        endpoints: what the core's Zenoh session connects to (the service session's private link: a Unix
            socket, or a loopback listener with a made-up login; in client mode the routers the service connects to).
        credentials: the user and password the core's link logs in with (a secured service's made-up
            user, :func:`~bridge.service.security.grant_internal_user`);
        zid: the Zenoh id the core's session takes (a secured service without a users file: its ACL allows
            that id on the private Unix socket, :func:`~bridge.service.security.grant_internal_socket`).
            Both are sent over the private socket, never on the command line, where every user of the
            computer could read them.
    """

    def __init__(
        self,
        config: ServiceConfig,
        endpoints: list[str],
        on_note: Callable[[dict[str, Any]], None] | None = None,
        credentials: Credentials | None = None,
        zid: str | None = None,
    ):
        self.config, self.endpoints = config, list(endpoints)
        self.on_note = on_note
        self.credentials, self.zid = credentials, zid
        self.process: subprocess.Popen[bytes] | None = None
        self._conn: multiprocessing.connection.Connection | None = None
        self._send_lock = threading.Lock()
        self._pending: dict[int, Future[Any]] = {}
        self._pending_lock = threading.Lock()
        self._ids = itertools.count(1)
        self._reader: threading.Thread | None = None
        self.ready: dict[str, Any] = {}
        self.ended: str | None = None
        """Why the core is gone (None while it runs)."""
        self._closing = threading.Event()  # ends the keep-alive thread

    def start(self) -> CoreProcess:
        mine, theirs = socket.socketpair()
        try:
            fd = theirs.fileno()
            self.process = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "bridge.service.core.process",
                    str(fd),
                    core_config_json(self.config),
                    json.dumps(self.endpoints),
                    *(["login"] if self.credentials is not None or self.zid is not None else []),
                ],
                pass_fds=(fd,),
                stdin=subprocess.DEVNULL,
                # a process group of its own: a Ctrl-C in the service's terminal (twice, from an impatient
                # operator) reaches the service, which closes the core; interrupting the core itself while it
                # closed its Zenoh session ended it with a traceback and 45 lines of "nanobind: leaked"
                process_group=0,
            )
        finally:
            theirs.close()
        self._conn = conn = multiprocessing.connection.Connection(mine.detach())
        if self.credentials is not None or self.zid is not None:  # the first message: the core's link
            creds = self.credentials
            user, password = (None, None) if creds is None else (creds.user, creds.password)
            try:
                conn.send(("login", user, password, self.zid))
            except OSError:  # the core ended already: reported below like any start that failed
                pass
        if not conn.poll(START_TIMEOUT_S):
            self.close()
            raise CoreError("unavailable", f"the control core did not start within {START_TIMEOUT_S:.0f} s")
        try:
            _, status, *rest = conn.recv()
        except (EOFError, OSError):
            code = self.process.wait(5.0) if self.process is not None else None
            self.close()
            raise CoreError("unavailable", f"the control core ended while starting (exit code {code})") from None
        if status != "ok":
            self.close()
            raise CoreError("unavailable", f"the control core could not start: {rest[-1]}")
        self.ready = dict(rest[0])
        self._reader = threading.Thread(target=self._read, name="core-replies", daemon=True)
        self._reader.start()
        threading.Thread(target=self._keep_alive, name="core-keepalive", daemon=True).start()
        return self

    def _keep_alive(self) -> None:
        """Every :data:`KEEPALIVE_S`: ``alive`` to the core (no answer; module docstring), until it ends."""
        conn = self._conn
        assert conn is not None
        while self.ended is None and not self._closing.is_set():
            try:
                with self._send_lock:
                    conn.send((0, "alive", (), {}))
            except (OSError, ValueError):
                return
            self._closing.wait(KEEPALIVE_S)

    @property
    def pid(self) -> int | None:
        return None if self.process is None else self.process.pid

    @property
    def alive(self) -> bool:
        return self.ended is None and self.process is not None and self.process.poll() is None

    def _read(self) -> None:
        conn = self._conn
        assert conn is not None
        while True:
            try:
                call_id, status, *rest = conn.recv()
            except (EOFError, OSError):
                break
            if status == "note":
                ended = rest[0].get("core_ended") if isinstance(rest[0], dict) else None
                if ended is not None:  # the core ends itself, and says why (a CAN thread stopped)
                    self.ended = self.ended or f"the control core ended: {ended}"
                    continue
                hook = self.on_note
                if hook is not None:
                    try:
                        hook(dict(rest[0]))
                    except Exception:  # noqa: BLE001 — a recorder's bug must not stop the replies
                        pass
                continue
            with self._pending_lock:
                fut = self._pending.pop(call_id, None)
            if fut is None:
                continue  # its caller gave up waiting
            if status == "ok":
                fut.set_result(rest[0])
            else:
                fut.set_exception(CoreError(str(rest[0]), str(rest[1])))
        with self._pending_lock:  # the calls waiting fail first: a stop must not wait for the exit status
            pending, self._pending = list(self._pending.values()), {}
        for fut in pending:
            fut.set_exception(CoreError("unavailable", self.ended or "the control core ended"))
        if self.process is not None:
            try:  # its socket closed as it died: the exit status follows at once (poll() said None: not reaped yet)
                self.process.wait(timeout=1.0)
            except subprocess.TimeoutExpired:
                pass
        self.ended = self.ended or self.end_reason()

    def end_reason(self) -> str:
        """Why the core ended, from its exit status (the same words whichever thread asks first: the reader above,
        or :func:`~bridge.service.server.serve`'s watch that may reap it before)."""
        if self.ended is not None:
            return self.ended
        code = None if self.process is None else self.process.poll()
        how = (
            "its exit status not known yet"
            if code is None
            else f"killed by signal {-code}"
            if code < 0
            else f"exit code {code}"
        )
        return f"the control core ended ({how})"

    def call(self, method: str, *args: Any, timeout_s: float = CALL_TIMEOUT_S, **kwargs: Any) -> Any:
        """Call ``method`` of the core; its value or :class:`CoreError` (the API's code)."""
        conn = self._conn
        if conn is None or self.ended is not None:
            raise CoreError("unavailable", self.ended or "the control core is not running")
        call_id = next(self._ids)
        fut: Future[Any] = Future()
        with self._pending_lock:
            self._pending[call_id] = fut
        try:
            with self._send_lock:
                conn.send((call_id, method, args, kwargs))
        except (OSError, ValueError) as exc:
            with self._pending_lock:
                self._pending.pop(call_id, None)
            raise CoreError("unavailable", f"the control core cannot be reached ({exc})") from None
        try:
            return fut.result(timeout=timeout_s)
        except FutureTimeout:
            with self._pending_lock:
                self._pending.pop(call_id, None)
            raise CoreError("busy", f"{method}: the control core did not answer within {timeout_s:.1f} s") from None

    def close(self, timeout_s: float = 2.0) -> None:
        """Ask the core to brake and end, then make sure it did (killed after ``timeout_s``)."""
        self._closing.set()
        if self._conn is not None and self.ended is None and self.process is not None and self.process.poll() is None:
            try:
                self.call("close", timeout_s=timeout_s)
            except CoreError:
                pass
        self.ended = self.ended or "closed"
        if self.process is not None:
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(1.0)
        if self._conn is not None:
            try:
                self._conn.close()
            except OSError:
                pass


class MotionProxy:
    """What the API uses of a motion controller, answered by the core process (module docstring).

    ``planner``: a planner of the service's own (pure computations on the model: goal vectors,
    workspace checks), never the core's.
    """

    def __init__(self, core: CoreProcess, planner: TrajectoryPlanner):
        self.core, self.planner = core, planner
        self._t0 = float(core.ready["t0_monotonic"])
        self._mode: str | None = None  # the core's mode as last heard (set_mode replies, the core's mode notes)

    def on_mode_note(self, mode: Any) -> None:
        """The core's new mode, noted over the private socket after each change (in order): kept
        without asking the core (``config`` is read at any rate by any client; it must not cost the
        core anything). Never from the public ``events`` key: anyone may put an event there."""
        if isinstance(mode, str):
            self._mode = mode

    def clock(self) -> float:
        """The core's clock [s]."""
        return time.monotonic() - self._t0

    @property
    def mode(self) -> str:
        if self._mode is None:
            self._mode = str(self.core.call("mode"))
        return self._mode

    @property
    def faults(self) -> list[dict[str, Any]]:
        return list(self.core.call("faults"))

    def current_state(self) -> MotionState:
        st = self.core.call("current_state")
        if not isinstance(st, MotionState):
            raise CoreError("internal", f"current_state returned {type(st).__name__}")
        return st

    def preview_start(self) -> MotionState:
        st = self.core.call("preview_start")
        if not isinstance(st, MotionState):
            raise CoreError("internal", f"preview_start returned {type(st).__name__}")
        return st

    def goto(
        self,
        goal: Mapping[str, float],
        speed_scale: float = 1.0,
        *,
        kind: str = "goto",
        label: str | None = None,
        deadline: float | None = None,
        issued: float | None = None,
    ) -> JsonReply:
        wait = CALL_TIMEOUT_S if deadline is None else max(0.5, deadline - self.clock() + 2.0)
        data = self.core.call(
            "goto",
            dict(goal),
            float(speed_scale),
            kind=kind,
            label=label,
            deadline=deadline,
            issued=issued,
            timeout_s=wait,
        )
        return JsonReply(data)

    def jog(
        self,
        rates: Mapping[str, float],
        ttl_s: float,
        *,
        deadline: float | None = None,
        issued: float | None = None,
        holder: str | None = None,
    ) -> JsonReply:
        return JsonReply(
            self.core.call("jog", dict(rates), float(ttl_s), deadline=deadline, issued=issued, holder=holder)
        )

    def stop(self, reason: str = "stop requested") -> int | None:
        mid = self.core.call("stop", reason)
        return None if mid is None else int(mid)

    def stop_report(self, reason: str = "stop requested") -> dict[str, Any]:
        return dict(self.core.call("stop_report", reason))

    def run_maneuver(
        self, validated: Any, name: str | None, *, deadline: float | None = None, issued: float | None = None
    ) -> int:
        wait = CALL_TIMEOUT_S if deadline is None else max(0.5, deadline - self.clock() + 2.0)
        return int(self.core.call("run_maneuver", validated, name, deadline=deadline, issued=issued, timeout_s=wait))

    def set_mode(self, mode: str) -> str:
        self._mode = str(self.core.call("set_mode", mode))
        return self._mode

    def ack_faults(self) -> JsonReply:
        return JsonReply(self.core.call("ack_faults"))

    def track_start(
        self,
        frame: str,
        dofs: tuple[str, ...],
        ttl_s: float,
        *,
        deadline: float | None = None,
        issued: float | None = None,
        replace: bool | int = False,
        caller: str = "track/start",
    ) -> JsonReply:
        return JsonReply(
            self.core.call(
                "track_start",
                frame,
                tuple(dofs),
                float(ttl_s),
                deadline=deadline,
                issued=issued,
                replace=replace,
                caller=caller,
            )
        )

    def track_setpoint(
        self, session: int, seq: int, pose: Mapping[str, float], velocity: Mapping[str, float] | None = None
    ) -> dict[str, Any]:
        return dict(
            self.core.call("track_setpoint", session, seq, dict(pose), None if velocity is None else dict(velocity))
        )

    def track_setpoint_refused(self, session: object, message: str) -> None:
        """A ``track/setpoint`` query the schema refused: counted against its session by the core, as a put is."""
        self.core.call("track_setpoint_refused", session, str(message))

    def track_stop(self, session: int | None = None, last_seq: int | None = None) -> dict[str, Any]:
        return dict(self.core.call("track_stop", session, last_seq))

    def post_event(self, event: Mapping[str, Any]) -> None:
        """Announce ``event`` through the core's controller (numbered in order with its own)."""
        self.core.call("post_event", dict(event))

    def maneuver_control(
        self, action: str, *, deadline: float | None = None, issued: float | None = None
    ) -> dict[str, Any]:
        return dict(self.core.call("maneuver_control", action, deadline=deadline, issued=issued))

    def lines_request(self, op: str, name: str | None = None, geojson: Any = None) -> dict[str, Any]:
        return dict(self.core.call("lines_request", op, name, geojson))

    def distance_travelled(self) -> float | None:
        d = self.core.call("distance_travelled")
        return None if d is None else float(d)

    def sim_fault(self, settings: Mapping[str, Any]) -> JsonReply:
        return JsonReply(self.core.call("sim_fault", dict(settings)))

    def sim_switch(self, position: str) -> list[str]:
        """``sim/switch``: the core's simulated tractor sends one press of the operator switch."""
        return list(self.core.call("sim_switch", position))

    def work_call(self, op: str, *args: Any) -> dict[str, Any]:
        """``work/…``: the core's work control (:meth:`bridge.service.work.WorkControl.dispatch`)."""
        return dict(self.core.call("work", op, *args))

    def select_implement(self, implement: Any, limits: Any, *, announce: bool = True) -> dict[str, Any]:
        """The implement (an ImplementRecord or None) and its ImplementLimits for the core's guards
        (``announce``: as :meth:`bridge.service.motion.controller.MotionController.select_implement`)."""
        return dict(self.core.call("select_implement", implement, limits, announce=announce))
