"""The WebSocket side of the operator terminal: fan-out of state and events, commands in.

:class:`ClientHub` lives on the web server's asyncio loop. For each page it keeps a *slot* with
the newest state message (a slow page skips states, it never builds a backlog: what it draws is
always the latest; the same for the hitch picture's ``view`` message, and the ``terminal``
message once) and a bounded queue of events (events are not skipped unless a page falls
200 behind). Commands ``{"id", "key", "payload"}`` are answered ``{"type": "reply", "id", "ok",
"data"}`` through the service handler, run on a thread pool by the ``call`` coroutine the server
hands in, as the page's user. Jog commands of one page are serialised: while one is in the handler
only the newest waits (older ones are answered ``busy``), so a page holding a jog button never
queues motion. ``stop`` is never answered ``busy`` and never waits for the page's other commands.

With a login (a :class:`~.sessions.SessionStore`), a page's WebSocket belongs to its session:
every command but ``stop`` needs the session still open (otherwise it is answered
``unauthenticated`` and the socket closes with 4401) and the session's CSRF token in the
command's ``csrf`` field (otherwise ``forbidden``); a page whose session ends (expiry, logout)
is closed with 4401 too.
"""

from __future__ import annotations

import asyncio
import collections
import json
import re
import time
from collections.abc import Awaitable, Callable
from typing import Any

from bridge.web.sessions import Session, SessionStore
from bridge.web.settings import json_safe
from bridge.web.websocket import WebSocket
from planner.errors import HitchInputError

__all__ = [
    "ClientHub",
    "Call",
    "CommandError",
    "CommandRate",
    "EVENTS_KEPT",
    "MAX_PENDING",
    "MAX_PAYLOAD_DEPTH",
    "API_NAME",
    "CLOSE_SESSION_ENDED",
    "CLOSE_TOO_MANY_COMMANDS",
    "parse_command",
    "COMMAND_FIELDS",
    "MAX_COMMAND_RATE_HZ",
    "COMMAND_BURST",
    "MAX_COMMAND_BYTES_PER_S",
    "COMMAND_BURST_BYTES",
]

#: ``call(name, body_bytes, user) -> (ok, reply)`` on the server's loop
#: ``call(name, body, user, received)``: the server's request path; ``received`` the message's arrival
#: (``time.monotonic()``), so a command held back here (a jog behind a jog) is judged by when it came
Call = Callable[[str, bytes, "str | None", float], Awaitable[tuple[bool, dict]]]
#: WebSocket close code when the page's session ended or was never valid (4000-4999: application codes)
CLOSE_SESSION_ENDED = 4401
#: events kept per page (and for pages that connect later)
EVENTS_KEPT = 200
#: commands of one page in the handler at once; more are answered ``busy``
MAX_PENDING = 32
#: a service API name: ``goto``, ``presets/save``, ``maneuvers/record/start`` …
API_NAME = re.compile(r"^[a-z]+(/[a-z]+){0,2}$")
#: commands a page may send per second on average, and in a burst (the page itself sends at most ~40 a
#: second: a held jog button 12.5, levelling 10, the work panel 10; after a network stall the kernel's send
#: buffer delivers its backlog at once: 1000 covers 25 s of it); a page above it is closed (1008)
MAX_COMMAND_RATE_HZ = 100.0
COMMAND_BURST = 1000
#: bytes of commands a page may send per second on average [B/s], and in a burst [B] (a maneuver script, the
#: largest payload, is at most 96 KiB)
MAX_COMMAND_BYTES_PER_S = 256 * 1024
COMMAND_BURST_BYTES = 512 * 1024
#: levels a payload may nest (the service's ``bridge.service.schemas.MAX_PAYLOAD_DEPTH``: the web layer does not
#: import the service; a test checks they agree), said when a command nests too deeply to be read at all
MAX_PAYLOAD_DEPTH = 32
#: WebSocket close code of a page that sent more than the rates above (RFC 6455 §7.4.1: policy violation)
CLOSE_TOO_MANY_COMMANDS = 1008
#: the fields of a command; any other is refused (a misspelt ``payloads`` ran the command without its payload)
COMMAND_FIELDS = ("id", "key", "payload", "csrf")


class CommandError(HitchInputError):
    """A WebSocket command that is not ``{"id", "key", "payload"}`` as the page sends it."""


class CommandRate:
    """Token buckets of one page: ``rate_hz`` commands a second with bursts of ``burst``, and
    ``bytes_per_s`` with bursts of ``burst_bytes``. :meth:`take` is False once a command exceeds either.

    A page that floods the terminal with commands (a fuzzer sent thousands of tiny frames a second) kept
    the server's loop busy parsing and answering them, and an HTTP ``stop`` waited 3.6–7.5 s behind it.
    """

    def __init__(
        self,
        rate_hz: float = MAX_COMMAND_RATE_HZ,
        burst: int = COMMAND_BURST,
        bytes_per_s: float = MAX_COMMAND_BYTES_PER_S,
        burst_bytes: int = COMMAND_BURST_BYTES,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not (rate_hz > 0 and burst >= 1 and bytes_per_s > 0 and burst_bytes >= 1):
            raise ValueError("CommandRate: rates and bursts must be positive")
        self.rate_hz, self.burst, self.bytes_per_s, self.burst_bytes = rate_hz, burst, bytes_per_s, burst_bytes
        self._clock = clock
        self._t = clock()
        self._commands, self._bytes = float(burst), float(burst_bytes)

    def take(self, size_bytes: int) -> bool:
        """Count one command of ``size_bytes``; False when it is over the page's rate."""
        now = self._clock()
        dt, self._t = max(0.0, now - self._t), now
        self._commands = min(float(self.burst), self._commands + dt * self.rate_hz)
        self._bytes = min(float(self.burst_bytes), self._bytes + dt * self.bytes_per_s)
        if self._commands < 1.0 or self._bytes < size_bytes:
            return False  # not taken: nothing spent
        self._commands -= 1.0
        self._bytes -= size_bytes
        return True

    def describe(self) -> str:
        return (
            f"at most {self.rate_hz:g} commands a second (bursts of {self.burst}) and "
            f"{self.bytes_per_s / 1024:g} KiB a second (bursts of {self.burst_bytes // 1024} KiB)"
        )


class _Client:
    """One page: the newest state (a slot), pending events, jog serialisation, running tasks."""

    def __init__(self, ws: WebSocket, state: str | None, session: Session | None, user: str | None):
        self.ws = ws
        self.state = state
        self.session = session
        self.user = user
        self.events: collections.deque[str] = collections.deque(maxlen=EVENTS_KEPT)
        self.wake = asyncio.Event()
        self.jog_busy = False
        self.jog_next: tuple[Any, bytes, float] | None = None  # (id, body, arrival) of a jog held back
        self.tasks: set[asyncio.Task] = set()
        self.view: str | None = None  # the newest ``view`` message (a slot, like the state)
        self.rate = CommandRate()
        self.terminal: str | None = None  # the ``terminal`` message, once
        if state is not None:
            self.wake.set()


class ClientHub:
    """All connected pages of one web server (use from its event loop only)."""

    def __init__(
        self,
        call: Call,
        hello: dict,
        sessions: SessionStore | None = None,
        command_rate: Callable[[], CommandRate] = CommandRate,
    ):
        self._call = call
        self._command_rate = command_rate  # each page's own buckets
        self.hello = hello
        self.sessions = sessions
        self._clients: set[_Client] = set()
        self.state_text: str | None = None
        self.view_text: str | None = None
        self.terminal_text: str | None = None

    def __len__(self) -> int:
        return len(self._clients)

    # ------------------------------------------------------------------ fan-out
    def state(self, state: dict) -> None:
        """A new state message for every page (encoded once)."""
        self.state_text = json.dumps({"type": "state", "data": json_safe(state)}, allow_nan=False)
        for c in self._clients:
            c.state = self.state_text
            c.wake.set()

    def view(self, view: dict) -> None:
        """A new ``view`` message (the hitch picture's points) for every page; newest only, like the state."""
        self.view_text = json.dumps({"type": "view", "data": json_safe(view)}, allow_nan=False)
        for c in self._clients:
            c.view = self.view_text
            c.wake.set()

    def terminal(self, terminal: dict) -> None:
        """The ``terminal`` message (what the picture needs once) for every page, and for pages to come."""
        self.terminal_text = json.dumps({"type": "terminal", "data": json_safe(terminal)}, allow_nan=False)
        for c in self._clients:
            c.terminal = self.terminal_text
            c.wake.set()

    def event(self, event: dict) -> None:
        text = json.dumps({"type": "event", "data": json_safe(event)}, allow_nan=False)
        for c in self._clients:
            c.events.append(text)
            c.wake.set()

    async def close_all(self, code: int = 1001, reason: str = "service shutting down") -> None:
        for c in list(self._clients):
            await c.ws.close(code, reason)
            c.wake.set()

    async def close_session(self, token: str, reason: str = "logged out") -> None:
        """Close the pages of one session (4401), e.g. at logout."""
        for c in list(self._clients):
            if c.session is not None and c.session.token == token:
                await c.ws.close(CLOSE_SESSION_ENDED, reason)
                c.wake.set()

    def _session_alive(self, c: _Client) -> bool:
        return c.session is None or (self.sessions is not None and self.sessions.get(c.session.token) is not None)

    # ------------------------------------------------------------------ one page
    async def serve(self, ws: WebSocket, session: Session | None = None, user: str | None = None) -> None:
        """Run one page until its WebSocket closes; its commands run as ``session.user`` (with a
        login) or ``user`` (without)."""
        if self.sessions is not None and session is None:
            await ws.close(CLOSE_SESSION_ENDED, "log in first")
            return
        who = session.user if session is not None else user
        client = _Client(ws, self.state_text, session, who)
        client.rate = self._command_rate()
        client.terminal, client.view = self.terminal_text, self.view_text
        if client.terminal is not None or client.view is not None:
            client.wake.set()
        self._clients.add(client)
        sender = asyncio.create_task(self._sender(client))
        hello = {**self.hello, "user": who, "role": None if session is None else session.role}
        hello["login"] = self.sessions is not None
        try:
            await ws.send_text(json.dumps({"type": "hello", "data": json_safe(hello)}, allow_nan=False))
            while True:
                if ws.buffered:  # frames read already: recv returns without waiting, so give the other
                    await asyncio.sleep(0)  # pages and HTTP requests (a stop) their turn first
                msg = await ws.recv()
                if msg is None:
                    break
                if not client.rate.take(len(msg)):
                    await self._flooded(client, msg)
                    break
                if len(client.tasks) >= MAX_PENDING and not _is_stop(msg):
                    await self._reply(
                        client,
                        _lenient_id(msg),
                        False,
                        {"error": "busy", "message": f"more than {MAX_PENDING} commands of this page pending"},
                    )
                    continue
                task = asyncio.create_task(self._command(client, msg))
                client.tasks.add(task)
                task.add_done_callback(client.tasks.discard)
        except (ConnectionError, OSError):
            pass
        finally:
            self._clients.discard(client)
            client.wake.set()
            await ws.close(1000)
            sender.cancel()

    async def _flooded(self, c: _Client, msg: str | bytes) -> None:
        """A page over its command rate: a stop among its commands still stops; the page is told and closed."""
        if _is_stop(msg):
            await self._command(c, msg)
        await self._reply(
            c,
            _lenient_id(msg),
            False,
            {
                "error": "busy",
                "message": f"this page sent commands faster than the terminal takes ({c.rate.describe()}): "
                "closed (the page connects again by itself)",
            },
        )
        await c.ws.close(CLOSE_TOO_MANY_COMMANDS, "too many commands")

    async def _sender(self, c: _Client) -> None:
        try:
            while not c.ws.closed:
                await c.wake.wait()
                c.wake.clear()
                if not self._session_alive(c):
                    await c.ws.close(CLOSE_SESSION_ENDED, "session expired: log in again")
                    return
                if c.terminal is not None:
                    text, c.terminal = c.terminal, None
                    await c.ws.send_text(text)
                while c.events:
                    await c.ws.send_text(c.events.popleft())
                if c.state is not None:
                    text, c.state = c.state, None
                    await c.ws.send_text(text)
                if c.view is not None:
                    text, c.view = c.view, None
                    await c.ws.send_text(text)
        except (ConnectionError, OSError, asyncio.CancelledError):
            return

    async def _command(self, c: _Client, msg: str | bytes) -> None:
        received = time.monotonic()  # a command's deadline counts from here, and a later stop cancels it
        stop = _as_stop(msg)
        if stop is not None:  # whatever else came with it (a NaN, an odd id, a repeated field), a stop stops
            held, c.jog_next = c.jog_next, None  # a jog held back behind another never runs after the stop
            ok, reply = await self._call("stop", b"", c.user, received)
            await self._reply(c, _reply_id(stop.get("id")), ok, reply)
            if held is not None:
                await self._reply(c, held[0], False, {"error": "busy", "message": "jog: cancelled by a stop"})
            return
        try:
            rid, key, body, csrf = parse_command(msg)
        except CommandError as exc:
            await self._reply(c, _lenient_id(msg), False, {"error": "bad_request", "message": str(exc)})
            return
        if key != "stop" and c.session is not None:  # stop needs no session: anyone may stop the hitch
            if not self._session_alive(c):
                await self._reply(
                    c, rid, False, {"error": "unauthenticated", "message": f"{key}: session expired; log in again"}
                )
                await c.ws.close(CLOSE_SESSION_ENDED, "session expired: log in again")
                return
            if not c.session.csrf_ok(csrf):
                await self._reply(
                    c,
                    rid,
                    False,
                    {"error": "forbidden", "message": f"{key}: missing or wrong CSRF token (reload the page)"},
                )
                return
        if key == "jog":
            await self._jog(c, rid, body, received)
            return
        ok, reply = await self._call(key, body, c.user, received)
        await self._reply(c, rid, ok, reply)

    async def _jog(self, c: _Client, rid, body: bytes, received: float) -> None:
        if c.jog_busy:
            if c.jog_next is not None:  # superseded before it ran: answer it so the page is not left waiting
                await self._reply(
                    c, c.jog_next[0], False, {"error": "busy", "message": "jog: superseded by a newer jog command"}
                )
            c.jog_next = (rid, body, received)
            return
        c.jog_busy = True
        try:
            nxt: tuple[Any, bytes, float] | None = (rid, body, received)
            while nxt is not None:
                ok, reply = await self._call("jog", nxt[1], c.user, nxt[2])
                await self._reply(c, nxt[0], ok, reply)
                nxt, c.jog_next = c.jog_next, None
        finally:
            c.jog_busy = False

    async def _reply(self, c: _Client, rid, ok: bool, reply: dict) -> None:
        try:
            await c.ws.send_text(
                json.dumps({"type": "reply", "id": rid, "ok": ok, "data": json_safe(reply)}, allow_nan=False)
            )
        except (ConnectionError, OSError):
            pass


class _DuplicateField(HitchInputError):
    def __init__(self, name: str):
        self.name = name
        super().__init__(f"duplicate key {name!r}")


def _unique_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object whose every field appears once (``json.loads`` keeps the last of two silently)."""
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateField(k)
        out[k] = v
    return out


def parse_command(msg: str | bytes) -> tuple[int | str | None, str, bytes, Any]:
    """A page's command ``{"id", "key", "payload", "csrf"}`` → ``(id, key, payload as UTF-8 JSON, csrf)``.

    :class:`CommandError` in the words the service's own parser uses for the same payload over HTTP
    (``goto: duplicate key 'z' in the payload …``, ``… more than 4300 digits …``), naming the key when it
    can be read. NaN and Infinity stay tokens in the payload: the service refuses them naming the field.
    """
    try:
        data = json.loads(msg, object_pairs_hook=_unique_pairs)
    except _DuplicateField as exc:
        key = _lenient_key(msg)
        where = "in the payload" if key else "in the command"
        raise CommandError(
            f"{key or 'command'}: duplicate key {exc.name!r} {where} (each field may appear once)"
        ) from None
    except RecursionError:
        raise CommandError(
            f"command: nests too deeply (allowed: at most {MAX_PAYLOAD_DEPTH} levels in its payload)"
        ) from None
    except UnicodeDecodeError as exc:
        raise CommandError(f"command: not UTF-8 text (byte {exc.start}); a command is JSON text") from None
    except ValueError as exc:  # JSONDecodeError, integers of more than 4300 digits
        if "Exceeds the limit" in str(exc):  # Python's int parser (its message names sys.set_int_max_str_digits)
            raise CommandError(
                f"{_lenient_key(msg) or 'command'}: payload holds an integer of more than 4300 digits "
                "(no field takes one)"
            ) from None
        raise CommandError(f"command: not valid JSON ({str(exc)[:80]}); a command is {{id, key, payload}}") from None
    if not isinstance(data, dict):
        raise CommandError("command: a command is a JSON object {id, key, payload}")
    rid, key, payload, csrf = data.get("id"), data.get("key"), data.get("payload", {}), data.get("csrf")
    if rid is not None and _reply_id(rid) is None:
        raise CommandError("command: id must be an integer or a string")
    if not isinstance(key, str) or not API_NAME.match(key):
        raise CommandError(f"command: key must be a service API name such as 'goto', got {key!r}")
    unknown = [k for k in data if k not in COMMAND_FIELDS]
    if unknown:
        raise CommandError(f"{key}: unknown field {unknown[0]!r} in the command (allowed: {', '.join(COMMAND_FIELDS)})")
    try:
        body = json.dumps(payload, ensure_ascii=False).encode("utf-8")  # as sent: UTF-8, not \\u escapes
    except UnicodeEncodeError as exc:  # a lone surrogate escape ("\\ud800") is no character
        bad = exc.object[exc.start : exc.end] if isinstance(exc.object, str) else ""
        raise CommandError(
            f"{key}: payload holds {ascii(bad)}, a lone UTF-16 surrogate escape, not a character"
        ) from None
    return _reply_id(rid), key, body, csrf


def _lenient(msg: str | bytes) -> dict | None:
    """The command read leniently (a repeated field keeps its last value), or None when it is no JSON object."""
    try:
        data = json.loads(msg)
    except (ValueError, TypeError, RecursionError):
        return None
    return data if isinstance(data, dict) else None


def _lenient_key(msg: str | bytes) -> str | None:
    data = _lenient(msg)
    key = None if data is None else data.get("key")
    return key if isinstance(key, str) and API_NAME.match(key) else None


def _lenient_id(msg: str | bytes) -> int | str | None:
    """The id a reply to this command carries, when it can be read at all (a busy or bad-request reply)."""
    data = _lenient(msg)
    return None if data is None else _reply_id(data.get("id"))


def _reply_id(rid: Any) -> int | str | None:
    """A command's id as its reply carries it (an integer or a string), or None."""
    return rid if isinstance(rid, (int, str)) and not isinstance(rid, bool) else None


def _as_stop(msg: str | bytes) -> dict | None:
    """The command if it is a ``stop`` (read leniently: NaN tokens, repeated fields), else None."""
    try:
        data = json.loads(msg)
    except (ValueError, TypeError, RecursionError):
        return None
    return data if isinstance(data, dict) and data.get("key") == "stop" else None


def _is_stop(msg: str | bytes) -> bool:
    """Does this raw command look like a ``stop`` (so it skips the pending-commands limit)?"""
    return _as_stop(msg) is not None
