"""The client side of the service (the CLI, the bench and the tests use it).

:class:`HitchClient` opens its own Zenoh session (client mode by default: it connects, it does not
listen), sends JSON queries to ``<prefix>/<key>`` and returns the reply as a dict or raises
:class:`ServiceError` carrying the service's ``error`` code and ``message``.
:meth:`HitchClient.fleet` lists the live services through their liveliness tokens
(``**/alive``): each token's key minus ``/alive`` is a service's key prefix. Track mode
(``docs/tracking.md``): :meth:`HitchClient.track_start`, :meth:`~HitchClient.track_setpoint` (a Zenoh
put, never blocking) and :meth:`~HitchClient.track_stop`.

A client with a :attr:`HitchClient.user` (by default the user its security file logs in as) sends every
request but ``stop`` on ``<prefix>/user/<user>/<key>``: the service then admits its expensive requests
against that user's own allowance, owns what it stores by that user and records it under that name. With
access control on, Zenoh lets a user send only their own such keys (``docs/security.md``).

``HitchClient(realtime=True)`` is for an operator's program on a busy computer: its ``stop`` must leave
the process at once, not after the CPU-bound programs beside it had their turn. The process's Zenoh
runtime threads (which send every query, ``stop`` too, and take every reply) then run under the
real-time policy ``SCHED_FIFO`` (:data:`~bridge.service.scheduling.CLIENT_RT_PRIORITY`, below the
service's control core; needs root or CAP_SYS_NICE, else a ``RuntimeWarning`` and
:attr:`HitchClient.realtime_refused` say why). Subscription callbacks run on a thread of ordinary
priority per subscription (every client's), never on those threads. The thread that calls
:meth:`~HitchClient.stop` runs under the same policy until the answer is in, then goes back to its own.
Measured (``docs/benchmarks.md``): under 20 load clients and two CPU-bound processes per core, the stop's way
from the client to the control core p99 0.5 ms with it against 74 ms without.

A client or subscription a program leaves open is closed at exit (each subscription's callback thread waited
for at most :data:`DISPATCH_JOIN_S`): the program exits, whatever its callbacks do.
"""

from __future__ import annotations

import atexit
import json
import math
import numbers
import os
import queue
import re
import threading
import time
import traceback
import warnings
import weakref
from collections.abc import Callable, Generator, Mapping, Sequence
from pathlib import Path
from typing import Any

import zenoh

from bridge.service.config import DEFAULT_LISTEN, validate_endpoint, validate_prefix
from bridge.service.scheduling import (
    CLIENT_RT_PRIORITY,
    caller_to_fifo,
    caller_to_ordinary,
    raise_to_fifo,
    zenoh_thread_ids,
)
from bridge.service.security import (
    SCOPE_NAME_RULE,
    apply_security,
    connect_sections,
    login_user,
    scopable_user,
    user_key,
)
from planner.errors import HitchInputError

__all__ = ["HitchClient", "ClientError", "ServiceError", "ServiceTimeout", "Subscription", "client_config"]

#: samples a subscription of a real-time client holds for its callback thread (the oldest dropped beyond)
SUBSCRIPTION_CAPACITY = 1024


class ClientError(HitchInputError):
    """A client setting or argument it cannot use; the message names it and the allowed values."""


class ServiceError(HitchInputError):
    """The service answered with an error: ``code`` (e.g. ``bad_request``) and its message.

    A :class:`~planner.errors.HitchInputError` (hence a ``ValueError``): the service refused the
    request it was given.
    """

    def __init__(self, code: str, message: str):
        self.code = code
        super().__init__(message)


class ServiceTimeout(ServiceError):
    """No answer within the timeout (service down, unreachable, or the key denied by access control).

    ``timeout_s``: the whole timeout [s] was spent on a query that went out (Zenoh ended it with its own
    ``Timeout`` reply, or it ran to its end): something took it but gave no answer — a service busy or hung
    (``hitch fleet ls``: NO ANSWER within …). None: nothing answered that key at all, or no query (a wait).
    ``link_lost``: a wait (:meth:`HitchClient.wait_motion`) ended because this client's session reached no
    router or peer for :data:`LINK_GRACE_S`: what the service did meanwhile is not known."""

    def __init__(self, message: str, *, timeout_s: float | None = None, link_lost: bool = False):
        super().__init__("timeout", message)
        self.timeout_s = timeout_s
        self.link_lost = link_lost


#: how long a wait (:meth:`HitchClient.wait_motion`) goes on while this client's session reaches no router or
#: peer, before it ends with a :class:`ServiceTimeout` (``link_lost``) instead of waiting out its timeout [s]
LINK_GRACE_S = 5.0
#: the events that end a maneuver (its outcome, :meth:`HitchClient.wait_maneuver`)
_MANEUVER_ENDS = ("maneuver_finished", "maneuver_aborted")
#: events a reply of ``events/recent`` holds at most (its ``limit``'s top)
_KEPT_PAGE = 500
#: how often a wait looks at the session's links [s]
LINK_POLL_S = 0.2
#: the payload of the error reply Zenoh itself gives a query whose timeout ran out (no service sends it)
ZENOH_TIMEOUT_REPLY = b"Timeout"


def client_config(connect: Sequence[str], *, mode: str = "client", security: str | Path | None = None) -> zenoh.Config:
    """Zenoh config of a client session: connect to ``connect``, no scouting, optional security file."""
    if mode not in ("client", "peer"):
        raise ClientError(f"mode must be 'client' or 'peer', got {mode!r}")
    eps = [validate_endpoint(e) for e in connect]
    if not eps:
        raise ClientError("connect: at least one endpoint is needed, e.g. tcp/127.0.0.1:7447")
    z = zenoh.Config()
    z.insert_json5("mode", json.dumps(mode))
    z.insert_json5("connect/endpoints", json.dumps(eps))
    z.insert_json5("scouting/multicast/enabled", "false")
    if mode == "peer":
        z.insert_json5("listen/endpoints", "[]")
    if security is not None:
        if mode == "client":  # it only connects: the login and TLS, never a users dictionary or access control
            for path, value in connect_sections(security).items():
                z.insert_json5(path, value)
        else:
            apply_security(z, security)
    return z


def zenoh_reason(exc: BaseException) -> str:
    """A Zenoh error in words, without the location in Zenoh's Rust source it carries ("… at
    /root/.cargo/git/checkouts/…/orchestrator.rs:447.": a fleet trial)."""
    return re.sub(r"\s+at\s+\S+\.rs:\d+\.?\s*$", "", str(exc)).strip()


def _json_value(value: Any) -> Any:
    """A numpy scalar or array as its Python value (``numpy.float32(0.1)`` raised a raw "Object of type float32
    is not JSON serializable": a fleet trial); anything else is refused naming its type."""
    if hasattr(value, "tolist") and callable(value.tolist):
        return value.tolist()
    raise TypeError(f"a {type(value).__name__} is not a JSON value (numbers, text, lists, mappings)")


def _goal(goal: Any) -> dict:
    """A goal mapping (``goto([0.1])`` raised a raw TypeError: a fleet trial)."""
    if not isinstance(goal, Mapping):
        raise ClientError(
            f"goal must be a mapping of x, z, roll, pitch to SI values (m, rad), e.g. {{'z': 0.1}}, got {goal!r}"
        )
    return dict(goal)


def _decode(payload: zenoh.ZBytes) -> Any:
    try:
        return json.loads(payload.to_bytes())
    except (ValueError, UnicodeDecodeError):
        return {"error": "bad_reply", "message": "the reply is not JSON"}


def _zenoh_timeout(err: Any) -> bool:
    """Is this error reply Zenoh's own for a query whose timeout ran out (payload ``Timeout``, no JSON)? Before, it
    was decoded as the service's and said "REFUSED (bad_reply): the reply is not JSON" for a hung service (a fleet
    trial)."""
    try:
        return err is not None and bytes(err.payload.to_bytes()).strip() == ZENOH_TIMEOUT_REPLY
    except Exception:  # noqa: BLE001 — not a reply of the shape Zenoh gives: not its timeout
        return False


def _error_reply(err: Any) -> ServiceError:
    """The :class:`ServiceError` of an error reply: the service's ``error`` code and ``message`` (JSON); an error
    that is no JSON (not the service's) as ``bad_reply`` with its text."""
    if err is None:
        return ServiceError("error", "the service refused")
    try:
        raw = bytes(err.payload.to_bytes())
    except Exception:  # noqa: BLE001
        raw = b""
    try:
        body = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        text = raw.decode("utf-8", "replace").strip()[:200]
        return ServiceError("bad_reply", f"the error reply is not the service's (not JSON): {text!r}")
    if not isinstance(body, dict):
        body = {}
    return ServiceError(str(body.get("error", "error")), str(body.get("message", "the service refused")))


def _undeclare(decl: Any) -> None:
    """Undeclare a Zenoh entity; undeclared already (``ZError``) is fine. A ``RuntimeError`` (seen once under
    load while its callback thread read its channel: the binding's object busy that instant) is tried again,
    for at most about 0.2 s; the caller's join then bounds the rest."""
    for attempt in range(10):
        try:
            decl.undeclare()
            return
        except zenoh.ZError:
            return
        except RuntimeError as exc:
            if attempt == 9:
                warnings.warn(f"could not undeclare a Zenoh entity ({exc}): it stays declared", RuntimeWarning, 2)
                return
            time.sleep(0.02)


class Subscription:
    """One :meth:`HitchClient.subscribe`; :meth:`close` ends it (idempotent; the client's ``close`` ends all)."""

    def __init__(self, subscriber: Any, owner: list[Subscription], dispatcher: threading.Thread | None = None) -> None:
        self._subscriber = subscriber
        self._owner = owner
        self._dispatcher = dispatcher  # the subscription's callback thread (None: Zenoh calls back itself)
        owner.append(self)
        if dispatcher is not None:  # closed at the latest at exit, before the interpreter finalizes (close)
            atexit.register(self._close_at_exit)

    def close(self) -> None:
        """Undeclare the subscriber: Zenoh delivers no sample after this returns. The callback thread hands
        over the samples it already holds and ends; this waits for it up to :data:`DISPATCH_JOIN_S` (not from
        a callback of this client: it may be what that thread waits for). A thread still inside Zenoh when the
        interpreter finalizes aborts the process, so one not seen to end here is waited for once more at exit
        (as is a subscription left open), again for at most that long."""
        self._close(at_exit=False)

    def _close_at_exit(self) -> None:
        self._close(at_exit=True)

    def _close(self, *, at_exit: bool) -> None:
        _undeclare(self._subscriber)
        try:
            self._owner.remove(self)
        except ValueError:  # closed already (by the client's close, or twice)
            pass
        th = self._dispatcher
        if th is None or not th.is_alive():
            if th is not None:
                atexit.unregister(self._close_at_exit)
            return
        if threading.current_thread().name.startswith(DISPATCH_THREAD_PREFIX):
            return  # from a callback: that thread, or another this one may hold up (joined at exit)
        th.join(DISPATCH_JOIN_S)
        if th.is_alive():
            warnings.warn(
                f"the callback of a subscription ({th.name}) has not returned {DISPATCH_JOIN_S:g} s after close"
                + ("; the process exits without it" if at_exit else "; it is waited for again at exit"),
                RuntimeWarning,
                stacklevel=3,
            )
            if not at_exit:
                return
        atexit.unregister(self._close_at_exit)


#: the clients not closed yet: closed at exit (weakly held: a client dropped unclosed leaves the set)
_OPEN_CLIENTS: weakref.WeakSet[HitchClient] = weakref.WeakSet()


def _close_open_clients() -> None:
    """At exit: close every client still open (its subscriptions' own exit hooks ran first: registered later)."""
    for client in list(_OPEN_CLIENTS):
        try:
            client.close()
        except Exception:  # noqa: BLE001 — at exit: one client's failure must not keep the others open
            traceback.print_exc()


atexit.register(_close_open_clients)

#: the name of a subscription's callback thread starts with this
DISPATCH_THREAD_PREFIX = "hitch-client-"
#: how long closing a subscription waits for its callback thread to end [s]
DISPATCH_JOIN_S = 2.0


def _dispatch(subscriber: Any, callback: Callable[[dict], None]) -> None:
    """A subscription: take the samples from the channel on a daemon thread of ordinary priority; a
    callback's exception is printed and the subscription goes on (as with Zenoh's own callbacks). The
    thread runs under the ordinary policy even when the thread that subscribed is real-time."""
    caller_to_ordinary()
    for sample in subscriber:  # ends when the subscriber is undeclared or the session closes
        try:
            callback(_decode(sample.payload))
        except Exception:  # noqa: BLE001 — the user's callback; one bad sample must not end the stream
            traceback.print_exc()


def _plain(v: Any) -> Any:
    """A number as Python's own (``np.int64(300)`` → ``300``, ``np.float32(0.5)`` → ``0.5``), for a field whose
    range the service checks and names; anything else as it is (the service refuses it in its words)."""
    if isinstance(v, bool):
        return v
    if isinstance(v, numbers.Integral):
        return int(v)
    if isinstance(v, numbers.Real):
        return float(v)
    return v


def _integer(name: str, v: Any, lo: int) -> int:
    """``v`` as a Python ``int`` >= ``lo``: any integer, numpy's too (``np.int64(2)``), or a float with no
    fraction (``2.0``, as the service takes it); :class:`ClientError` naming ``name`` otherwise (a bool, text,
    ``2.5``, NaN). Before, a numpy integer was refused as "seq must be an integer >= 0, got np.int64(2)"."""
    if not isinstance(v, bool):  # (numpy's bool_ is no number: refused below)
        if isinstance(v, numbers.Integral):
            n = int(v)
            if n >= lo:
                return n
        elif isinstance(v, numbers.Real):
            f = float(v)
            if math.isfinite(f) and f.is_integer() and f >= lo:
                return int(f)
    raise ClientError(f"{name} must be an integer >= {lo}, got {v!r}")


def _real(name: str, v: Any) -> float:
    """``v`` as a finite Python ``float``: any real number, numpy's too (``np.float32(0.12)``); :class:`ClientError`
    naming ``name`` otherwise. Before, a numpy ``float32`` was refused as "must be a finite number"."""
    if not isinstance(v, bool) and isinstance(v, numbers.Real):
        f = float(v)
        if math.isfinite(f):
            return f
    raise ClientError(f"{name} must be a finite number [SI: m, rad, m/s, rad/s], got {v!r}")


def _setpoint_body(session: int, seq: int, pose: Mapping[str, float], velocity: Mapping[str, float] | None) -> bytes:
    """The JSON of one ``track/setpoint``; :class:`ClientError` naming the field for a value the service
    would refuse anyway (never a NaN on the wire). Numbers may be numpy's (sent as Python's)."""
    body: dict[str, Any] = {"session": _integer("session", session, 1), "seq": _integer("seq", seq, 0)}
    if pose is None:  # before: a body without a pose was put, refused by the service unseen (a new user's report)
        raise ClientError(
            "pose is required: a mapping of every DOF the session tracks (x, z [m], roll, pitch [rad]), got None"
        )
    for what, m in (("pose", pose), ("velocity", velocity)):
        if m is None:
            continue
        if not isinstance(m, Mapping) or not m:
            raise ClientError(f"{what} must be a non-empty mapping of x, z, roll, pitch to SI values, got {m!r}")
        out: dict[str, float] = {}
        for k, val in m.items():
            if k not in ("x", "z", "roll", "pitch"):
                raise ClientError(f"{what}: unknown field {k!r}; allowed: x, z, roll, pitch")
            out[k] = _real(f"{what}.{k}", val)
        body[what] = out
    data = json.dumps(body).encode("utf-8")
    if not _within_setpoint_bounds(body):  # a put is not answered: say now what the service would refuse
        from bridge.service.schemas import RequestError, parse_request  # its own words (and unit hints)

        try:
            parse_request("track/setpoint", data)
        except RequestError as exc:
            raise ClientError(str(exc)) from None
    return data


#: what an API key looks like (``goto``, ``maneuvers/record/stop``): checked before the key reaches Zenoh
_API_KEY_SHAPE = re.compile(r"[a-z][a-z_]*(/[a-z][a-z_]*)*")


def _within_setpoint_bounds(body: Mapping[str, Any]) -> bool:
    """The setpoint's pose [m, rad] and velocity [m/s, rad/s] within the service's bounds (the cheap check
    before the service's own refusal is asked for its words)."""
    from bridge.service.maneuvers.steps import POSE_BOUNDS, SETPOINT_VELOCITY_BOUND

    pose, vel = body.get("pose") or {}, body.get("velocity") or {}
    return all(POSE_BOUNDS[k][0] <= v <= POSE_BOUNDS[k][1] for k, v in pose.items()) and all(
        abs(v) <= SETPOINT_VELOCITY_BOUND for v in vel.values()
    )


class HitchClient:
    """A Zenoh session to one service (``prefix``) or a fleet (``fleet()``, per-call prefixes)."""

    def __init__(
        self,
        connect: Sequence[str] = (DEFAULT_LISTEN,),
        *,
        prefix: str = "hitch",
        timeout_s: float = 5.0,
        security: str | Path | None = None,
        mode: str = "client",
        realtime: bool = False,
        user: str | None = None,
    ):
        """``realtime``: run this process's Zenoh threads under ``SCHED_FIFO`` (module docstring) so a
        ``stop`` leaves at once however busy the computer is; :attr:`realtime_refused` says why not when
        the system does not permit it (None: granted, or not asked for).

        ``user``: send every request but ``stop`` as this user, on ``<prefix>/user/<user>/<key>``, so the
        service admits, stores and records it as theirs (default: the user the security file logs in as,
        when that name can be a key chunk; ``""``: the shared keys). Only to a service that serves them
        (its ``config`` says ``user_keys``, asked once per prefix): one whose access control lets each user
        send only their own (``docs/security.md``); to any other the plain keys are used."""
        self.prefix = validate_prefix(prefix)
        if user is None and security is not None:
            login = login_user(security)
            user = login if scopable_user(login) else ""
        if user and not scopable_user(user):
            raise ClientError(f"user {user!r} cannot name request keys (allowed: {SCOPE_NAME_RULE})")
        #: the user this client's requests are sent as (None: the shared keys)
        self.user: str | None = user or None
        self._user_keys: dict[str, bool] = {}  # prefix -> does that service serve user keys (its config)
        if not 0 < timeout_s <= 600:
            raise ClientError(f"timeout_s must lie in (0, 600] s, got {timeout_s!r}")
        self.timeout_s = float(timeout_s)
        try:
            self.session = zenoh.open(client_config(connect, mode=mode, security=security))
        except zenoh.ZError as exc:
            raise ServiceError(
                "connect",
                f"cannot open a Zenoh session to {', '.join(connect)}: {zenoh_reason(exc)} (is the router or service "
                "running there? a wrong password or certificate is refused the same way)",
            ) from None
        self._subs: list[Subscription] = []
        _OPEN_CLIENTS.add(self)  # closed at exit if still open (_close_open_clients)
        self.realtime = bool(realtime)
        self.realtime_refused: str | None = None
        self._tasks_seen = -1  # this process's thread count when its Zenoh threads were last raised
        if self.realtime:
            self._keep_realtime()
        self._track_lock = threading.Lock()
        self._track_pub: tuple[str, int, Any] | None = None  # (key, session, publisher) of the live setpoint stream

    # ------------------------------------------------------------------ requests
    def request(
        self,
        key: str,
        payload: Mapping | bytes | str | None = None,
        *,
        prefix: str | None = None,
        timeout_s: float | None = None,
    ) -> dict:
        """Query ``<prefix>/<key>`` (``<prefix>/user/<user>/<key>`` when this client has a :attr:`user`,
        except ``stop``, which anyone may send and which must not wait for anything); the reply dict, or
        :class:`ServiceError`; :class:`ClientError` for a key that is no API key's shape (``""``, a trailing
        ``/``, ``?`` or ``#`` raised Zenoh's own error with a Rust source path, or went out as a selector)."""
        if not isinstance(key, str) or not _API_KEY_SHAPE.fullmatch(key):
            raise ClientError(
                f"key must be an API key such as 'goto' or 'presets/save' (lower-case words joined by '/'), got "
                f"{key!r} (the keys: docs/api.md)"
            )
        base = validate_prefix(prefix) if prefix else self.prefix
        t = self.timeout_s if timeout_s is None else timeout_s
        scoped = self.user is not None and key != "stop" and self._serves_user_keys(base, t)
        full = user_key(base, self.user, key) if scoped and self.user is not None else f"{base}/{key}"
        if isinstance(payload, Mapping):
            try:  # UTF-8 as it is: the size limit counts bytes
                data: bytes | str = json.dumps(payload, ensure_ascii=False, default=_json_value)
            except (TypeError, ValueError) as exc:  # a value JSON cannot carry: said, not a raw TypeError
                raise ClientError(f"{key}: the payload cannot be sent as JSON ({exc})") from None
        else:
            data = b"" if payload is None else payload
        return self._query(full, key, data, t)

    def _serves_user_keys(self, base: str, timeout_s: float) -> bool:
        """Does the service at ``base`` serve user keys? Its ``config`` says (asked once; not remembered
        when it does not answer, so a service started later is asked again)."""
        known = self._user_keys.get(base)
        if known is None:
            t0 = time.monotonic()
            try:
                reply = self._query(f"{base}/config", "config", b"{}", timeout_s)
            except ServiceTimeout as exc:
                if time.monotonic() - t0 < 0.8 * timeout_s:
                    return False  # nothing answered at once (e.g. an access list without it): the plain keys
                raise ServiceTimeout(  # the whole timeout spent already: not once more for the request itself
                    f"no reply from {base} within {timeout_s:g} s (asked {base}/config; is the service running "
                    "and reachable, and may this user use that key?)",
                    timeout_s=exc.timeout_s if exc.timeout_s is not None else timeout_s,
                ) from None
            except ServiceError:
                return False
            known = self._user_keys[base] = reply.get("user_keys") is True
        return known

    def _query(self, full: str, key: str, data: bytes | str, t: float) -> dict:
        qos: dict[str, Any] = {}
        if key == "stop":  # ahead of everything else on every link it crosses, never dropped
            qos = {
                "priority": zenoh.Priority.REAL_TIME,
                "express": True,
                "congestion_control": zenoh.CongestionControl.BLOCK,
            }
        t0 = time.monotonic()
        # the stop's query is built under this thread and its answer wakes it: real-time until the answer is in
        restore = caller_to_fifo(CLIENT_RT_PRIORITY) if key == "stop" and self.realtime else None
        timed_out = False  # Zenoh's own Timeout reply: the query went out, no answer came within t
        try:
            for reply in self.session.get(full, payload=data, timeout=t, **qos):
                if reply.ok is not None:
                    return _decode(reply.ok.payload)
                if _zenoh_timeout(reply.err):
                    timed_out = True
                    break
                raise _error_reply(reply.err)
        finally:
            if restore is not None:
                restore()
            if self.realtime:  # Zenoh starts some runtime threads at first use: raise those too
                self._keep_realtime()
        waited = time.monotonic() - t0
        if waited < 0.8 * t and not timed_out:  # the query ended early without an answer: nothing answers that key
            raise ServiceTimeout(
                f"no reply from {full}: nothing answered that key ({waited:.2f} s, before the {t:g} s timeout); "
                "is the prefix right, is the service running and reachable, and may this user use that key?"
            )
        raise ServiceTimeout(
            f"no reply from {full} within {t:g} s: the query went out but no answer came (a service busy or hung, "
            "or an access list that drops this user's query of that key)",
            timeout_s=t,
        )

    def ik(self, x: float, z: float, roll: float, pitch: float) -> dict:
        """The service's inverse kinematics of a pose: ``x``, ``z`` [m], ``roll``, ``pitch`` [rad] → its reply
        (``status``, ``actuators`` [rad, m], ``pose``, ``active`` limits; ``docs/api.md``). Nothing moves."""
        return self.request("ik", {"x": x, "z": z, "roll": roll, "pitch": pitch})

    def plan(self, goal: Mapping[str, float], speed_scale: float = 1.0) -> dict:
        """A goto's plan from where the hitch is to ``goal`` (x, z [m], roll, pitch [rad]; partial), checked by
        the guard, at ``speed_scale`` (0.05…1) of the limits: duration, guard decision, limits. Nothing moves."""
        return self.request("plan", {"goal": _goal(goal), "speed_scale": speed_scale})

    def goto(self, goal: Mapping[str, float], speed_scale: float = 1.0, *, deadline_ms: int | None = None) -> dict:
        """Start a move; ``deadline_ms``: it must start moving within this, else ``busy`` (service default 1000)."""
        body: dict[str, Any] = {"goal": _goal(goal), "speed_scale": speed_scale}
        if deadline_ms is not None:
            body["deadline_ms"] = int(deadline_ms)
        return self.request("goto", body)

    def jog(
        self, vx: float = 0.0, vz: float = 0.0, vroll: float = 0.0, vpitch: float = 0.0, ttl_ms: float = 200.0
    ) -> dict:
        """Start or refresh a jog: pose rates ``vx``, ``vz`` [m/s], ``vroll``, ``vpitch`` [rad/s] for ``ttl_ms``
        [ms]; send it again within ``ttl_ms`` to keep moving (a dead man's button), else the hitch brakes."""
        return self.request("jog", {"vx": vx, "vz": vz, "vroll": vroll, "vpitch": vpitch, "ttl_ms": ttl_ms})

    def stop(self) -> dict:
        """Stop: brake jerk-limited to rest, abort a maneuver, cancel motion requests sent before it
        (``{"stopped": true, "motion_id", "ended": [what it aborted besides the motion, e.g. "maneuver 'mw' at step
        1 (index 0)"], "t"}``; any payload stops, ``docs/faults.md``)."""
        return self.request("stop", {})

    def ack_faults(self) -> dict:
        """Acknowledge the latched faults (``faults/ack``, operators): ``{"acknowledged": [...], "faults": [...]}``."""
        return self.request("faults/ack", {})

    def sim_fault(self, settings: Mapping[str, Any]) -> dict:
        """Inject faults in the twin (``sim/fault``, operators; refused ``unavailable`` with a real ECU):
        ``{"cut": "none"|"planner_to_ecu"|"ecu_to_planner"|"both", "loss": 0…1, "delay_ms": ≥ 0,
        "restart_ecu": bool}``; missing keys mean no fault."""
        return self.request("sim/fault", dict(settings))

    def mode(self, mode: str | None = None) -> dict:
        """The operating mode (``auto``, ``manual``, ``attach``, ``transport``, ``config``: ``docs/api.md``);
        ``mode`` given: switch to it (refused while moving)."""
        return self.request("mode", {} if mode is None else {"mode": mode})

    # ------------------------------------------------------------------ track mode (docs/tracking.md)
    def track_start(
        self,
        frame: str = "tractor",
        dof: Sequence[str] = ("z",),
        ttl_ms: int = 200,
        *,
        deadline_ms: int | None = None,
        replace: bool = False,
    ) -> dict:
        """Start a track session (``track/start``, operators): setpoints of ``dof`` (a subset of x, z,
        roll, pitch) in ``frame`` (``tractor``, ``level``, ``ground``); without a setpoint within
        ``ttl_ms`` (50…1000 ms) the hitch brakes to rest and the session ends; ``deadline_ms``: it must
        start within this, else ``busy`` (service default 1000). Another session whose stream is live is
        refused ``busy`` unless ``replace`` (it then ends, ``replaced by track``). The reply:
        ``{"accepted", "session", "motion_id", "frame", "dof", "ttl_ms"}``."""
        if isinstance(dof, str):
            raise ClientError(f"dof must be a list of DOF names such as ['x', 'z'], got the string {dof!r}")
        body: dict[str, Any] = {"frame": frame, "dof": list(dof), "ttl_ms": _plain(ttl_ms)}
        if replace:
            body["replace"] = True
        if deadline_ms is not None:  # (int() made 2.7 ms 2 and raised a raw ValueError for text)
            body["deadline_ms"] = _plain(deadline_ms)
        return self.request("track/start", body)

    def maneuver_control(self, action: str, *, deadline_ms: int | None = None) -> dict:
        """``pause``, ``resume`` or ``skip`` the running maneuver (``maneuvers/<action>``, operators;
        docs/maneuvers.md). ``deadline_ms`` (resume, skip): it and the step it leads to must start within
        this, else ``busy`` or the maneuver aborts (service default 1000); a pause takes none."""
        if action not in ("pause", "resume", "skip"):
            raise ClientError(f"action must be one of pause, resume, skip, got {action!r}")
        if action == "pause" and deadline_ms is not None:
            raise ClientError("pause only brakes: it takes no deadline_ms")
        return self.request(f"maneuvers/{action}", {} if deadline_ms is None else {"deadline_ms": int(deadline_ms)})

    def save_maneuver(self, name: str, script: str, *, replace: bool = False) -> dict:
        """Store a maneuver script (YAML) as ``name`` (``maneuvers/save``, operators): ``{"saved", "steps"}``.
        A name saved already is refused (``in_use``, :class:`ServiceError`) unless ``replace``; the reply of
        a save that replaced one also says ``"replaced": true`` (docs/maneuvers.md)."""
        body: dict[str, Any] = {"name": name, "script": script}
        if replace:
            body["replace"] = True
        return self.request("maneuvers/save", body)

    def record_stop(self, name: str | None = None, *, replace: bool = False) -> dict:
        """End teach-in (``maneuvers/record/stop``): ``{"script", "steps"}``; with ``name`` also saved as
        ``name`` (``saved``, or ``not_saved`` saying why). A name saved already is refused (``in_use``) and the
        recording goes on, unless ``replace``."""
        if replace and name is None:
            raise ClientError("replace needs a name: the maneuver the recording replaces")
        body: dict[str, Any] = {} if name is None else {"name": name}
        if replace:
            body["replace"] = True
        return self.request("maneuvers/record/stop", body)

    def track_setpoint(
        self,
        session: int,
        seq: int,
        pose: Mapping[str, float],
        velocity: Mapping[str, float] | None = None,
    ) -> None:
        """Stream one setpoint (a Zenoh put on ``track/setpoint``, express, priority DATA_HIGH, dropped
        rather than queued under congestion: it never blocks and gets no answer). ``pose`` [m, rad]:
        every DOF of the session in its frame; ``velocity`` [m/s, rad/s] optional; ``seq`` strictly
        increasing (the service ignores older ones). Refusals show in the state's ``track`` entry
        (``rejected``, ``last_rejection``) and as ``track_setpoint_rejected`` events. One publisher per
        session, declared at its first setpoint and reused."""
        data = _setpoint_body(session, seq, pose, velocity)
        with self._track_lock:
            key = f"{self.prefix}/track/setpoint"
            cur = self._track_pub
            if cur is None or cur[0] != key or cur[1] != session:
                if cur is not None:
                    _undeclare(cur[2])
                pub = self.session.declare_publisher(
                    key,
                    encoding=zenoh.Encoding.APPLICATION_JSON,
                    express=True,
                    congestion_control=zenoh.CongestionControl.DROP,
                    priority=zenoh.Priority.DATA_HIGH,
                )
                cur = self._track_pub = (key, session, pub)
            cur[2].put(data)

    def track_setpoint_request(
        self,
        session: int,
        seq: int,
        pose: Mapping[str, float],
        velocity: Mapping[str, float] | None = None,
        *,
        timeout_s: float | None = None,
    ) -> dict:
        """The same setpoint as a query: ``{"accepted", "limited", …}`` or :class:`ServiceError` naming
        why it was refused (e.g. the first setpoint of a stream, to see a bad value at once)."""
        return self.request("track/setpoint", _setpoint_body(session, seq, pose, velocity), timeout_s=timeout_s)

    def track_stop(
        self, session: int | None = None, *, last_seq: int | None = None, timeout_s: float | None = None
    ) -> dict:
        """End the live track session smoothly (``track/stop``; ``session`` None: whichever is live):
        ``{"stopping", "session", "motion_id"}`` (and ``after_seq`` while it waits for ``last_seq``);
        the setpoint publisher of that session is released. ``last_seq``: the last setpoint streamed —
        a put may arrive after this query; the service takes it before braking (waits at most the ttl)."""
        body: dict[str, int] = {} if session is None else {"session": _integer("session", session, 1)}
        if last_seq is not None:
            body["last_seq"] = _integer("last_seq", last_seq, 0)
        try:
            return self.request("track/stop", body, timeout_s=timeout_s)
        finally:
            with self._track_lock:
                cur = self._track_pub
                if cur is not None and (session is None or cur[1] == session):
                    _undeclare(cur[2])
                    self._track_pub = None

    def config(self, prefix: str | None = None) -> dict:
        """The service's configuration and limits (profile, workspace [m, rad], jog velocity, …); ``prefix``: of
        another service of the fleet."""
        return self.request("config", {}, prefix=prefix)

    def recent_events(self, after: int = 0, *, prefix: str | None = None) -> dict:
        """The events numbered above ``after`` the service still keeps (``events/recent``): ``{"events", "oldest",
        "latest", "missed", "more", "instance"}`` — for a client whose subscription missed some (a router restart,
        a radio gap). ``instance``: the run they belong to (``config``'s)."""
        return self.request("events/recent", {"after": after}, prefix=prefix)

    # ------------------------------------------------------------------ subscriptions
    def subscribe(self, what: str, callback: Callable[[dict], None], *, prefix: str | None = None) -> Subscription:
        """Call ``callback(dict)`` for every ``state`` or ``events`` sample until the returned
        :class:`Subscription` or this client is closed, on a daemon thread of ordinary priority of the
        subscription's own (at most :data:`SUBSCRIPTION_CAPACITY` samples waiting, the oldest dropped
        beyond): keep it short. Left open, it is closed at exit (waiting at most :data:`DISPATCH_JOIN_S`
        for that thread); a callback run by Zenoh's own thread (a non-daemon thread) held the exit forever."""
        if what not in ("state", "events"):
            raise ClientError(f"what must be 'state' or 'events', got {what!r}")
        key = f"{validate_prefix(prefix) if prefix else self.prefix}/{what}"
        sub = self.session.declare_subscriber(key, zenoh.handlers.RingChannel(SUBSCRIPTION_CAPACITY))
        th = threading.Thread(
            target=_dispatch, args=(sub, callback), name=f"{DISPATCH_THREAD_PREFIX}{what}", daemon=True
        )
        th.start()
        if self.realtime:
            self._keep_realtime()
        return Subscription(sub, self._subs, th)

    def _keep_realtime(self) -> None:
        """Raise this process's Zenoh threads to ``SCHED_FIFO`` when their number changed since the last
        time (Zenoh starts some at first use); the first refusal is kept and warned about once."""
        if not os.path.isdir("/proc/self/task"):
            self._refuse_realtime("the system has no /proc/self/task to find Zenoh's threads in")
            return
        n = len(os.listdir("/proc/self/task"))
        if n == self._tasks_seen:
            return
        self._tasks_seen = n
        failed = raise_to_fifo(zenoh_thread_ids(), CLIENT_RT_PRIORITY)
        if failed:
            self._refuse_realtime(
                "; ".join(sorted(set(failed))) + " (needs CAP_SYS_NICE: root has it unless it was dropped)"
            )

    def _refuse_realtime(self, why: str) -> None:
        if self.realtime_refused is None:
            self.realtime_refused = why
            warnings.warn(
                f"HitchClient(realtime=True): Zenoh's threads stay at ordinary priority: {why}",
                RuntimeWarning,
                stacklevel=4,  # the caller's line (HitchClient(...), where it is found first)
            )

    def follow(self, what: str = "state", *, timeout_s: float | None = None) -> Generator[dict, None, None]:
        """Iterate over samples; a :class:`ServiceTimeout` when none arrives within the timeout."""
        q: queue.Queue = queue.Queue(maxsize=1000)

        def put(d: dict) -> None:
            try:
                q.put_nowait(d)
            except queue.Full:
                pass

        sub = self.subscribe(what, put)
        t = self.timeout_s if timeout_s is None else timeout_s
        try:
            while True:
                try:
                    yield q.get(timeout=t)
                except queue.Empty:
                    raise ServiceTimeout(f"no {self.prefix}/{what} sample within {t:g} s") from None
        finally:  # the caller stopped iterating (break, close, garbage collection) or the timeout
            sub.close()

    def state(self, *, timeout_s: float | None = None) -> dict:
        """The next ``state`` sample."""
        samples = self.follow("state", timeout_s=timeout_s)
        try:
            return next(samples)
        finally:
            samples.close()

    def linked(self) -> bool:
        """Does this client's session reach a router or a peer now (Zenoh's session info)? False: nothing it sends
        arrives and no sample reaches it (in client mode: it lost its router; Zenoh reconnects by itself)."""
        try:
            info = self.session.info
            return any(True for _ in info.routers_zid()) or any(True for _ in info.peers_zid())
        except Exception:  # noqa: BLE001 — the session is closing: no link
            return False

    def wait_motion(self, motion_id: int, *, timeout_s: float = 60.0, link_grace_s: float | None = None) -> dict:
        """Block until the state shows that motion ``motion_id`` has ended; the state then. That state says *that*
        it ended, not *how*: its ``motion_id`` is ``motion_id`` at rest, or a newer motion's (the motion was replaced
        or aborted: a stop, a fault, a link loss starts a braking motion of its own). Its ``motion_finished`` /
        ``motion_aborted`` event (``events``, subscribed before the request) says how; without it the outcome is
        not known (a fleet trial: a wait through a router restart returned the stop's state of a motion the link
        loss had aborted, and ``hitch goto --wait`` called it a success).

        A restarted service (its state's ``seq`` goes back) ends the wait too: the motion is gone.

        :class:`ServiceTimeout` when it has not ended within ``timeout_s``, or (``link_lost``) as soon as this
        client's session has reached no router or peer for ``link_grace_s`` (default :data:`LINK_GRACE_S`): no
        state can then come, and the service may have stopped the motion (before, such a wait hung silently for
        its whole timeout). A maneuver is several motions: wait for it with :meth:`wait_maneuver`."""
        grace = LINK_GRACE_S if link_grace_s is None else float(link_grace_s)
        done = threading.Event()
        last: dict = {}

        def on_state(s: dict) -> None:
            seq, before = s.get("seq"), last.get("seq")
            last.update(s)
            mid = s.get("motion_id")
            if isinstance(mid, int) and (mid > motion_id or (mid == motion_id and not s.get("moving"))):
                done.set()
            elif isinstance(seq, int) and isinstance(before, int) and seq < before:
                # the service restarted: its motion is gone and it numbers its motions from 1 again (a review:
                # the wait ran to its timeout and said "still running"); how it ended is not known here
                done.set()

        sub = self.subscribe("state", on_state)
        end = time.monotonic() + timeout_s
        unlinked_since: float | None = None
        try:
            while not done.wait(max(0.0, min(LINK_POLL_S, end - time.monotonic()))):
                now = time.monotonic()
                if now >= end:
                    raise ServiceTimeout(f"motion {motion_id} still running after {timeout_s:g} s")
                if self.linked():
                    unlinked_since = None
                    continue
                unlinked_since = now if unlinked_since is None else unlinked_since
                if now - unlinked_since >= grace:
                    raise ServiceTimeout(
                        f"motion {motion_id}: the link to the service is lost — this client's session has reached no "
                        f"router or peer for {now - unlinked_since:.1f} s — so its end cannot be seen (the service "
                        "may have stopped it: a service that loses its router brakes, docs/faults.md)",
                        link_lost=True,
                    )
        finally:
            sub.close()
        return dict(last)

    def wait_maneuver(self, maneuver_id: int, *, timeout_s: float = 600.0, instance: str | None = None) -> dict:
        """Block until maneuver ``maneuver_id`` (a ``maneuvers/run`` reply's ``maneuver_id``) has finished or
        was aborted: ``{"outcome": its maneuver_finished / maneuver_aborted event (absent if none was heard or
        kept), "state": the last state (absent if none came)}``. A maneuver that ended before the wait began, or
        whose outcome event this client missed, is looked up in the events the service keeps (``events/recent``,
        the last 2000, newest first): a fleet trial's run, stop, wait got no outcome though the service had it.
        ``instance``: the run the maneuver belongs to (the reply's ``instance``): only that run's kept events
        count (a restarted service numbers its maneuvers from 1 again); None: the run answering now."""
        done, outcome_seen, state_seen = threading.Event(), threading.Event(), threading.Event()
        out: dict[str, Any] = {}
        seen = [False]
        t0 = time.monotonic()

        def on_event(e: dict) -> None:
            if e.get("maneuver_id") == maneuver_id and e.get("event") in _MANEUVER_ENDS:
                out["outcome"] = e
                outcome_seen.set()
                done.set()

        def on_state(s: dict) -> None:
            out["state"] = s
            state_seen.set()
            m = s.get("maneuver")
            if isinstance(m, dict) and m.get("maneuver_id", m.get("motion_id")) == maneuver_id:
                seen[0] = True
            elif seen[0] or time.monotonic() - t0 > 2.0:  # it ran and ended, or ended before we looked
                done.set()

        subs = (self.subscribe("events", on_event), self.subscribe("state", on_state))
        try:
            kept, instance = self._kept_maneuver_end(maneuver_id, instance)
            if kept is not None and "outcome" not in out:  # it ended before the subscriptions heard it
                out["outcome"] = kept
                outcome_seen.set()
                done.set()
                state_seen.wait(1.0)  # the state now, as for a wait that saw the end
            if not done.wait(timeout_s):
                raise ServiceTimeout(f"maneuver {maneuver_id} still running after {timeout_s:g} s")
            if not outcome_seen.wait(1.0):  # the outcome event follows the state that shows the end
                kept, _ = self._kept_maneuver_end(maneuver_id, instance)
                if kept is not None:
                    out["outcome"] = kept
        finally:
            for sub in subs:
                sub.close()
        return dict(out)

    def _kept_maneuver_end(self, maneuver_id: int, instance: Any) -> tuple[dict | None, Any]:
        """Maneuver ``maneuver_id``'s ``maneuver_finished`` / ``maneuver_aborted`` among the events the service
        keeps, searched newest first (500 a reply), and the run they belong to; ``instance`` given: only in that
        run (None once the service answers for another). (None, the run) when none is kept or nothing answered."""
        try:
            head = self.request("events/recent", {"after": 0, "limit": 1})
            run = head.get("instance")
            if instance is not None and run != instance:
                return None, instance
            latest, oldest = head.get("latest"), head.get("oldest")
            if not isinstance(latest, int) or not isinstance(oldest, int):
                return None, run
            hi = latest
            while hi >= oldest:  # pages (lo, hi], newest first: the maneuver ended lately, its end is near the top
                lo = max(oldest - 1, hi - _KEPT_PAGE)
                r = self.request("events/recent", {"after": lo, "limit": _KEPT_PAGE})
                if r.get("instance") != run:  # restarted meanwhile
                    return None, run
                for e in reversed([e for e in r.get("events") or () if isinstance(e, dict)]):
                    if e.get("maneuver_id") == maneuver_id and e.get("event") in _MANEUVER_ENDS:
                        return e, run
                hi = lo
        except ServiceError:  # not answered (busy, refused, no route): the outcome stays unknown
            return None, instance
        return None, run

    # ------------------------------------------------------------------ fleet
    def fleet(self, *, timeout_s: float = 2.0, under: str | None = None) -> list[str]:
        """Key prefixes of every live service (liveliness tokens ``<prefix>/alive``), sorted; with ``under``
        (a prefix without wildcards, e.g. ``fleet`` or ``fleet/t07/hitch``) only the services whose prefix is
        that one or begins with its chunks (``fleet`` lists ``fleet/t07/hitch``, not ``fleetwood/hitch``)."""
        out = set()
        selector = f"{validate_prefix(under)}/**/alive" if under is not None else "**/alive"
        for reply in self.session.liveliness().get(selector, timeout=timeout_s):
            if reply.ok is not None:
                k = str(reply.ok.key_expr)
                out.add(k[: -len("/alive")] if k.endswith("/alive") else k)
        return sorted(out)

    # ------------------------------------------------------------------ life cycle
    def close(self) -> None:
        """End the subscriptions (each waiting at most :data:`DISPATCH_JOIN_S` for its callback thread), the
        setpoint publisher and the session (idempotent). A client left open is closed so at exit."""
        _OPEN_CLIENTS.discard(self)
        with self._track_lock:
            if self._track_pub is not None:
                _undeclare(self._track_pub[2])
                self._track_pub = None
        for sub in list(self._subs):
            sub.close()
        if not self.session.is_closed():
            self.session.close()

    def __enter__(self) -> HitchClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
