"""The operator terminal's HTTP + WebSocket server, run inside the service process.

One asyncio loop in its own thread serves:

* ``GET /`` and the page's static files (``index.html``, ``app.js``, ``style.css``);
* ``POST /api/<name>`` with a JSON body — ``<name>`` is a service API name (``goto``,
  ``presets/save`` …). The body goes **unchanged** to the service's handler
  ``handle(name, body_bytes, user) -> (ok, reply)`` (:meth:`bridge.service.api.ServiceAPI.handle`,
  the function the Zenoh queryables call), so validation, precedence and access control are the
  service's own; in the service's lanes (:meth:`bridge.service.server.HitchService.dispatch`), as the
  queryables' requests: motion never queues behind planning or storage, the expensive ones are refused
  ``busy`` beyond a bounded queue, and every request is stamped with its arrival (a motion request that
  waited past its ``deadline_ms``, or was sent before a later stop, is refused, never run late).
  ``ok`` → 200 with the reply; otherwise the reply ``{"error", "message"}`` with the status from
  :data:`~.settings.ERROR_STATUS`;
* ``GET /api/state`` — the latest state message; ``GET /api/info`` — user and key prefix;
* ``GET /api/view`` — the hitch picture's numbers for the latest state (:mod:`.view`: the model's
  points for the measured and the target actuators); ``GET /api/terminal`` — what the picture
  needs once (ground, workspace, thresholds, the operator words of every limit code). Both 503
  while the model is still being built (it is built in the background when first asked for);
* ``GET /ws`` — a WebSocket (:class:`~.hub.ClientHub`): every state message the service
  publishes (50 Hz; a slow page gets the newest, never a backlog), every event, and command
  replies; besides, once ``{"type": "terminal"}`` and, at most :data:`~.view.VIEW_RATE_HZ` and
  only while a page is connected, ``{"type": "view"}`` (the same as ``/api/view``);
* ``GET /api/session``, ``POST /api/login`` ``{"user", "password"}``, ``POST /api/logout`` — the
  login (:mod:`.sessions`), when the terminal has accounts.

The state reaches the server through :meth:`WebServer.publish_state` /
:meth:`WebServer.publish_event` (thread-safe, never blocking). :func:`start_http` connects them
to the service's in-process listeners (``service.add_listener``), which receive the very dicts
the service puts on ``<prefix>/state`` and ``<prefix>/events``; :func:`attach_zenoh` does the
same from the Zenoh publications for a server outside the service process.

Security: loopback unless another address is configured; requests whose ``Host`` is not this
server (DNS rebinding) or whose ``Origin`` is another site (CSRF, cross-site WebSocket) are
refused. With access control on, the terminal has a login (:class:`~.sessions.Accounts`, the
users of the security file): everything but the page's static files, ``/api/session``,
``/api/login`` and ``stop`` needs a session cookie, every state-changing request the session's
CSRF token, and commands run as the logged-in user, whom the service's access policy refuses the
way it refuses that user over Zenoh. Without access control there is no login and commands run
as the configured ``user`` (normally none). ``stop`` runs on a thread of its own: it never waits
for other requests of the terminal, and any POST to ``/api/stop`` stops, whatever its body's type or
size (a JSON content type is required of every other request: a cross-site "simple" form post
cannot reach them), and whatever its body's framing: a chunked stop is served as soon as its header
is in (its chunks are read after the answer; the connection stays open if they are well formed and
within the size and time limits), one with a framing refused elsewhere (both ``Content-Length`` and
``Transfer-Encoding``, a coding other than chunked) is served and the connection closed. Every
other request may send its body chunked (:func:`~.http.read_chunked`: the same 96 KiB and 10 s limits).

Protocol answers: ``GET /ws`` without a WebSocket upgrade 426 (Upgrade Required); a request without a
``Host`` header 400 saying so; ``GET /api/<key>`` 405 "use POST" for a key of the API, 404
``unknown_key`` for a name that is none.
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
import math
import threading
import time
from collections.abc import Callable, Collection, Mapping
from concurrent.futures import Executor, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Protocol

from bridge.web.http import (
    BODY_TIMEOUT_S,
    MAX_DISCARD_BYTES,
    HttpError,
    HttpRequest,
    discard,
    json_response,
    read_chunked,
    read_request,
    response_bytes,
)
from bridge.web.hub import API_NAME, ClientHub
from bridge.web.sessions import (
    Accounts,
    LoginError,
    LoginThrottle,
    Session,
    SessionStore,
    clear_cookie,
    cookie_name,
    cookie_value,
    set_cookie,
)
from bridge.web.settings import ERROR_STATUS, WebSettings, host_allowed, json_safe, origin_allowed, parse_address
from bridge.web.view import VIEW_RATE_HZ, HitchView
from bridge.web.websocket import WebSocket, WebSocketError, accept_key
from planner.errors import HitchError, HitchInputError

__all__ = [
    "WebServer",
    "WebServerError",
    "WebServerStateError",
    "BindTimeout",
    "Handler",
    "Dispatch",
    "attach_zenoh",
    "start_http",
]

log = logging.getLogger("hitch.web")


class Handler(Protocol):
    """``handle(name, payload_bytes, user, *, received) -> (ok, reply)``: the service API's one entry point
    (:meth:`bridge.service.api.ServiceAPI.handle`); ``received``: ``time.monotonic()`` when the request
    arrived (a motion request's ``deadline_ms`` counts from then, and a stop sent after it cancels it)."""

    def __call__(self, key: str, payload: bytes, user: str | None, *, received: float) -> tuple[bool, dict]: ...


class Dispatch(Protocol):
    """``dispatch(name, payload_bytes, respond, *, received, user, inline)``: the service's lanes
    (:meth:`bridge.service.server.HitchService.dispatch`): answers by calling ``respond(ok, json_bytes)`` once,
    from a lane's thread (O(1) keys on ``inline``); never blocks the caller."""

    def __call__(
        self,
        key: str,
        payload: bytes,
        respond: Callable[[bool, bytes], None],
        *,
        received: float,
        user: str | None,
        inline: Executor | None,
    ) -> None: ...


#: paths whose POST is served whatever its body (type, size): whatever is sent to stop, stops
_ANY_BODY_PATHS = frozenset({"/api/stop"})
_STATIC = {"/": "index.html", "/index.html": "index.html", "/app.js": "app.js", "/style.css": "style.css"}
_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
}
_CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
    "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'"
)


class WebServerError(HitchInputError):
    """A web server that cannot be built from what it was given (no handler, no state source …)."""


class WebServerStateError(HitchError, RuntimeError):
    """The web server used out of order (started twice, asked for its address before it started)."""


class BindTimeout(HitchError, TimeoutError):
    """The web server's loop did not bind its address in time (an ``OSError``, like a taken port)."""


#: how long a failed login waits before its answer [s] (slows guessing on one connection)
LOGIN_FAILURE_DELAY_S = 0.5
#: the login routes (answered by the terminal, not the service)
_LOGIN_ROUTES = ("/api/session", "/api/login", "/api/logout")


def _error(status: int, code: str, message: str, keep_alive: bool = True) -> bytes:
    return json_response(status, {"error": code, "message": message}, keep_alive=keep_alive)


def _json(status: int, obj: Any, keep_alive: bool, headers: dict | None = None) -> bytes:
    body = json.dumps(json_safe(obj), allow_nan=False, separators=(",", ":")).encode("utf-8")
    return response_bytes(status, body, "application/json", headers=headers, keep_alive=keep_alive)


def _login_fields(body: bytes) -> tuple[str, str]:
    """``{"user", "password"}`` from a login body; :class:`LoginError` (400) naming the field otherwise
    (a field given twice too: never the last one wins, as for every API key)."""

    def once(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, v in pairs:
            if k in out:
                raise LoginError(f"login: duplicate key {k[:64]!r} (each field may appear once)", 400, "bad_request")
            out[k] = v
        return out

    try:
        data = json.loads(body or b"null", object_pairs_hook=once)
    except LoginError:
        raise
    except (ValueError, RecursionError):
        raise LoginError("login: the body must be JSON {user, password}", 400, "bad_request") from None
    if not isinstance(data, dict):
        raise LoginError("login: the body must be a JSON object {user, password}", 400, "bad_request")
    extra = sorted(set(data) - {"user", "password"})
    if extra:
        raise LoginError(f"login: unknown field {extra[0]!r} (allowed: user, password)", 400, "bad_request")
    out = []
    for name, limit in (("user", 64), ("password", 256)):
        v = data.get(name)
        if not isinstance(v, str) or not v or len(v) > limit:
            raise LoginError(f"login: {name} must be a string of 1-{limit} characters", 400, "bad_request")
        out.append(v)
    return out[0], out[1]


def _settle(answered: asyncio.Future, ok: bool, data: bytes) -> None:
    if not answered.done():  # a page that went away cancelled it
        answered.set_result((ok, data))


class WebServer:
    """HTTP + WebSocket front end of one service; see the module docstring.

    Args:
        handler: the service API handler (:data:`Handler`), called on a worker thread.
        settings: address, user, static files (:class:`~.settings.WebSettings`).
        info: extra fields for ``GET /api/info`` and the WebSocket hello (e.g. the key prefix).
        accounts: who may log in (:class:`~.sessions.Accounts`); None: no login, commands run as
            ``settings.user``.
        view: the hitch picture (:class:`~.view.HitchView`), or a function that builds one (called
            once, on a thread of its own, when a page or ``/api/view`` first needs it: building a
            model takes seconds); None: no picture (``/api/view`` answers 404).
        dispatch: the service's lanes (:class:`Dispatch`); every request but ``stop`` then goes through
            them, as the Zenoh queryables' do: motion on its own lane, the expensive ones on a bounded queue
            (``busy`` at once beyond it), each stamped with its arrival. None: every request on this
            server's own worker threads (stamped likewise).
    """

    def __init__(
        self,
        handler: Handler,
        settings: WebSettings | None = None,
        *,
        info: dict | None = None,
        accounts: Accounts | None = None,
        view: HitchView | Callable[[], HitchView] | None = None,
        dispatch: Dispatch | None = None,
        api_keys: Collection[str] | None = None,
    ):
        if not callable(handler):
            raise WebServerError("handler must be callable as handle(name, payload_bytes, user)")
        self.handler = handler
        #: the keys the handler serves (a GET of another is answered 'unknown key', of one of them 'use POST');
        #: None: every well-formed name counts as a key
        self.api_keys = None if api_keys is None else frozenset(api_keys)
        self._dispatch = dispatch
        self.settings = settings or WebSettings()
        self.accounts = accounts
        self.sessions = SessionStore(self.settings.session_ttl_s) if accounts is not None else None
        self.throttle = LoginThrottle()
        self.info = {"user": None if accounts is not None else self.settings.user, **(info or {})}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.base_events.Server | None = None
        self._thread: threading.Thread | None = None
        self._pool = ThreadPoolExecutor(self.settings.workers, thread_name_prefix="hitch-web")
        self._stop_pool = ThreadPoolExecutor(1, thread_name_prefix="hitch-web-stop")  # stop never queues
        self._hub = ClientHub(self._call, self.info, self.sessions)
        self._writers: set[asyncio.StreamWriter] = set()
        self._state: dict | None = None
        self._address: tuple[str, int] | None = None
        self._on_close: list[Callable[[], None]] = []
        self.counts = {"state": 0, "events": 0, "requests": 0, "views": 0}
        #: ``on_login(what, user, ok, reply)`` after every login, failed login and logout (the black box; never
        #: given the password): ``what`` is ``"web/login"`` or ``"web/logout"``
        self.on_login: Callable[[str, str | None, bool, dict], None] | None = None
        self._view: HitchView | None = view if isinstance(view, HitchView) else None
        self._view_factory: Callable[[], HitchView] | None = None if isinstance(view, HitchView) else view
        self._view_error: str | None = None
        self._view_building = False
        self._view_msg: dict | None = None
        self._view_at = -math.inf  # monotonic time of the last view message
        if self._view is not None:
            self._hub.terminal(self._view.terminal())

    # ------------------------------------------------------------------ life cycle
    def start(self, timeout_s: float = 5.0) -> WebServer:
        """Bind and serve in a background thread; raises OSError if the address cannot be bound."""
        if self._thread is not None:
            raise WebServerStateError("web server already started")
        ready = threading.Event()
        failure: list[BaseException] = []

        def run() -> None:
            loop = asyncio.new_event_loop()
            try:
                self._server = loop.run_until_complete(
                    asyncio.start_server(self._connection, self.settings.host, self.settings.port, limit=64 * 1024)
                )
                self._address = tuple(self._server.sockets[0].getsockname()[:2])
            except BaseException as exc:  # noqa: BLE001 — handed to the starting thread
                failure.append(exc)
                loop.close()
                ready.set()
                return
            self._loop = loop
            ready.set()
            try:
                loop.run_forever()
            finally:
                for task in asyncio.all_tasks(loop):
                    task.cancel()
                loop.run_until_complete(asyncio.sleep(0))
                loop.close()

        self._thread = threading.Thread(target=run, name="hitch-web-loop", daemon=True)
        self._thread.start()
        if not ready.wait(timeout_s):
            where = f"{self.settings.host}:{self.settings.port}"
            raise BindTimeout(f"web server did not bind {where} within {timeout_s} s")
        if failure:
            self._thread = None
            raise failure[0]
        if not self.settings.loopback:
            log.warning("operator terminal listens on %s (not loopback): anyone on that network can open it", self.url)
        return self

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) actually bound (port 0 → the chosen port)."""
        if self._address is None:
            raise WebServerStateError("web server not started")
        return self._address

    @property
    def url(self) -> str:
        host, port = self.address
        return f"http://[{host}]:{port}/" if ":" in host else f"http://{host}:{port}/"

    def close(self, timeout_s: float = 1.0) -> None:
        """Close every page's WebSocket (1001 'going away') and connection, stop listening, end the thread."""
        for undo in self._on_close:
            try:
                undo()
            except Exception:  # noqa: BLE001 — best effort at shutdown
                pass
        self._on_close.clear()
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or loop.is_closed():
            return

        async def shutdown() -> None:
            if self._server is not None:
                self._server.close()
            await self._hub.close_all(1001, "service shutting down")
            for w in list(self._writers):
                w.close()

        try:
            asyncio.run_coroutine_threadsafe(shutdown(), loop).result(timeout_s)
        except Exception:  # noqa: BLE001 — best effort at shutdown
            pass
        try:
            loop.call_soon_threadsafe(loop.stop)
        except RuntimeError:
            pass
        thread.join(timeout_s)
        self._thread = None
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._stop_pool.shutdown(wait=False, cancel_futures=True)

    def add_close_hook(self, fn: Callable[[], None]) -> None:
        """Call ``fn()`` first thing in :meth:`close` (e.g. to remove a state listener)."""
        self._on_close.append(fn)

    def __enter__(self) -> WebServer:
        return self.start() if self._thread is None else self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ feed (any thread)
    def _post(self, fn, arg) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(fn, arg)
            except RuntimeError:  # the loop closed between the check and the call
                pass

    def publish_state(self, state: dict) -> None:
        """Hand one ``<prefix>/state`` message (a dict) to every page; thread-safe, never blocks."""
        self._post(self._on_state, state)

    def publish_event(self, event: dict) -> None:
        """Hand one ``<prefix>/events`` message to every page; thread-safe, never blocks."""
        self._post(self._on_event, event)

    def _on_state(self, state: dict) -> None:
        self._state = state
        self.counts["state"] += 1
        self._hub.state(state)
        now = time.monotonic()
        # the picture: only while a page is connected, at most VIEW_RATE_HZ
        if self._view is not None and len(self._hub) > 0 and now - self._view_at >= 1.0 / VIEW_RATE_HZ:
            self._view_at = now
            self._send_view(state)

    # ------------------------------------------------------------------ the hitch picture (loop thread)
    def _send_view(self, state: dict) -> dict | None:
        view = self._view
        if view is None:
            return None
        try:
            msg = view.message(state)
        except Exception:  # noqa: BLE001 — a state the picture cannot take never stops the terminal
            log.exception("operator terminal: the hitch picture failed for state seq %s", state.get("seq"))
            return None
        self._view_msg = msg
        self.counts["views"] += 1
        self._hub.view(msg)
        return msg

    def _want_view(self) -> None:
        """Build the picture's model in the background the first time it is needed."""
        factory = self._view_factory
        if self._view is not None or factory is None or self._view_building or self._view_error is not None:
            return
        self._view_building = True

        def build() -> None:
            try:
                view = factory()
            except Exception as exc:  # noqa: BLE001 — reported on /api/view and in the log
                log.warning("operator terminal: no hitch picture: %s", exc)
                self._post(self._view_failed, f"{type(exc).__name__}: {exc}")
                return
            self._post(self._view_ready, view)

        threading.Thread(target=build, name="hitch-web-view", daemon=True).start()

    def _view_ready(self, view: HitchView) -> None:
        self._view, self._view_building = view, False
        self._hub.terminal(view.terminal())
        if self._state is not None and len(self._hub) > 0:
            self._view_at = time.monotonic()
            self._send_view(self._state)

    def _view_failed(self, why: str) -> None:
        self._view_error, self._view_building = why, False

    def _view_route(self, req: HttpRequest) -> bytes:
        ka = req.keep_alive
        if req.method != "GET":
            return _error(405, "bad_request", f"use GET for {req.path}", ka)
        if self._view is None:
            if self._view_factory is None:
                return _error(404, "not_found", "this terminal has no hitch picture (no model given)", ka)
            self._want_view()
            if self._view_error is not None:
                return _error(503, "unavailable", f"the hitch picture is unavailable: {self._view_error}", ka)
            return _error(503, "unavailable", "the hitch picture's model is being built; ask again shortly", ka)
        if req.path == "/api/terminal":
            return json_response(200, json_safe(self._view.terminal()), keep_alive=ka)
        if self._state is None:
            return _error(503, "unavailable", "the service has published no state yet", ka)
        msg = (
            self._send_view(self._state)
            if self._view_msg is None or self._view_msg.get("seq") != self._state.get("seq")
            else self._view_msg
        )
        if msg is None:
            return _error(500, "internal", "the hitch picture failed for the latest state (see the log)", ka)
        return json_response(200, json_safe(msg), keep_alive=ka)

    def _on_event(self, event: dict) -> None:
        self.counts["events"] += 1
        self._hub.event(event)

    # ------------------------------------------------------------------ HTTP
    async def _connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        try:
            while True:
                try:
                    req = await read_request(reader, any_body_paths=_ANY_BODY_PATHS)
                except HttpError as exc:
                    writer.write(_error(exc.status, exc.code, str(exc), keep_alive=False))
                    await writer.drain()
                    return
                if req is None:
                    return
                self.counts["requests"] += 1
                if req.path == "/ws" and req.header("upgrade").lower() == "websocket":
                    await self._websocket(req, reader, writer)
                    return
                writer.write(await self._respond(req))
                await writer.drain()
                if req.unread:  # a stop's body over the limit, not read: dropped before closing
                    await discard(reader, req.unread)
                if req.chunked:  # a stop's chunked body, served before it was read: read (and dropped) now
                    try:
                        await read_chunked(reader)
                    except HttpError as exc:  # answered already; where the next request would begin is unknown
                        log.info("operator terminal: closing after a stop whose chunked body failed: %s", exc)
                        await discard(reader, MAX_DISCARD_BYTES)
                        return
                if req.deferred:  # a stop's body, served before it was read: read (and dropped) now
                    try:
                        await asyncio.wait_for(reader.readexactly(req.deferred), BODY_TIMEOUT_S)
                    except (TimeoutError, asyncio.IncompleteReadError):
                        return  # answered already; the body never came whole: close
                if req.framing_unknown:  # a stop's body of unknown length: dropped (bounded) before closing
                    await discard(reader, MAX_DISCARD_BYTES)
                if not req.keep_alive:
                    return
        except (ConnectionError, OSError, asyncio.IncompleteReadError):
            return
        finally:
            self._writers.discard(writer)
            try:
                writer.close()
            except (ConnectionError, OSError, RuntimeError):
                pass

    def _check(self, req: HttpRequest) -> bytes | None:
        """The refusal for a request from elsewhere, or None."""
        if not req.header("host").strip():
            return _error(
                400,
                "bad_request",
                "the request has no Host header (or an empty one): every request must name the terminal's "
                "HOST:PORT in Host (DNS rebinding protection; HTTP/1.1 requires it)",
                req.keep_alive,
            )
        if not host_allowed(req.header("host"), self.address, self.settings):
            return _error(
                421,
                "forbidden",
                f"Host {req.header('host')!r} is not this server (DNS rebinding protection): open the "
                "terminal by its IP address, or name this HOST:PORT in the service's http_hosts "
                "(--http-host) if it is reached by that name",
                req.keep_alive,
            )
        if not origin_allowed(req.header("origin"), req.header("host")):
            return _error(
                403,
                "forbidden",
                f"Origin {req.header('origin')!r} may not use this terminal (cross-site request)",
                req.keep_alive,
            )
        return None

    # ------------------------------------------------------------------ login
    @property
    def login_required(self) -> bool:
        return self.sessions is not None

    def _cookie(self) -> str:
        return cookie_name(self.address[1])

    def _session(self, req: HttpRequest) -> Session | None:
        if self.sessions is None:
            return None
        return self.sessions.get(cookie_value(req.header("cookie"), self._cookie()))

    def _session_reply(self, s: Session | None) -> dict:
        store = self.sessions
        return {
            "login": store is not None,
            "authenticated": s is not None,
            "user": s.user if s is not None else (None if store is not None else self.settings.user),
            "role": None if s is None else s.role,
            "csrf": None if s is None else s.csrf,
            "expires_in_s": None if s is None or store is None else round(s.remaining_s(store.clock()), 1),
        }

    def _audit(self, what: str, user: str | None, ok: bool, reply: dict) -> None:
        hook = self.on_login
        if hook is None:
            return
        try:
            hook(what, user, ok, reply)
        except Exception:  # noqa: BLE001 — a recorder's bug must not fail the login
            log.exception("operator terminal: the login recorder failed")

    async def _login_route(self, req: HttpRequest) -> bytes:
        ka = req.keep_alive
        if req.path == "/api/session":
            if req.method != "GET":
                return _error(405, "bad_request", "use GET for /api/session", ka)
            return _json(200, self._session_reply(self._session(req)), ka)
        if req.method != "POST":
            return _error(405, "bad_request", f"use POST for {req.path}", ka)
        if req.path == "/api/logout":
            s = self._session(req)
            if s is not None and not s.csrf_ok(req.header("x-csrf-token")):
                return _error(403, "forbidden", "logout: missing or wrong X-CSRF-Token header", ka)
            if s is not None and self.sessions is not None:
                self.sessions.close(s.token)
                await self._hub.close_session(s.token)
                self._audit("web/logout", s.user, True, {"logged_out": True})
            headers = {"Set-Cookie": clear_cookie(self._cookie())} if self.sessions is not None else None
            return _json(200, {"logged_out": s is not None}, ka, headers)
        # /api/login
        if self.accounts is None or self.sessions is None:
            return _error(404, "not_found", "this terminal has no login (access control is off)", ka)
        if req.header("content-type").split(";")[0].strip().lower() != "application/json":
            return _error(415, "bad_request", "send the login with Content-Type: application/json", ka)
        user = ""
        try:
            user, password = _login_fields(req.body)
            self.throttle.check(user)
            role = self.accounts.verify(user, password)
        except LoginError as exc:
            if user:  # a refused login is recorded with the name it gave (a body without one: nothing to say)
                self._audit("web/login", user, False, {"error": exc.code, "message": str(exc)})
            if exc.code in ("unauthenticated", "forbidden") and user:
                self.throttle.failed(user)
                log.warning("operator terminal: failed login for %r", user)
                await asyncio.sleep(LOGIN_FAILURE_DELAY_S)
            return _error(exc.status, exc.code, str(exc), ka)
        self.throttle.succeeded(user)
        s = self.sessions.open(user, role)
        log.info("operator terminal: %s logged in as %s", user, role)
        self._audit("web/login", user, True, {"role": role})
        headers = {"Set-Cookie": set_cookie(self._cookie(), s.token, self.sessions.ttl_s)}
        return _json(200, self._session_reply(s), ka, headers)

    # ------------------------------------------------------------------ routes
    async def _respond(self, req: HttpRequest) -> bytes:
        ka = req.keep_alive
        refusal = self._check(req)
        if refusal is not None:
            return refusal
        if req.path in _LOGIN_ROUTES:
            return await self._login_route(req)
        if req.path in _STATIC:
            if req.method not in ("GET", "HEAD"):
                return _error(405, "bad_request", f"{req.method} is not allowed on {req.path}", ka)
            name = _STATIC[req.path]
            try:
                body = (self.settings.static_dir / name).read_bytes()
            except OSError:
                return _error(404, "not_found", f"{name} is missing from {self.settings.static_dir}", ka)
            return response_bytes(
                200,
                body,
                _TYPES[Path(name).suffix],
                headers={"Content-Security-Policy": _CSP},
                keep_alive=ka,
                head_only=req.method == "HEAD",
            )
        if req.path == "/favicon.ico":
            return response_bytes(204, keep_alive=ka)
        if req.path == "/ws":  # a WebSocket upgrade is served by _connection; anything else at /ws is not one
            return response_bytes(
                426,
                json.dumps(
                    {
                        "error": "bad_request",
                        "message": "/ws is the terminal's WebSocket: it needs a WebSocket upgrade "
                        "(GET with Upgrade: websocket, Connection: Upgrade, Sec-WebSocket-Version: 13)",
                    }
                ).encode(),
                "application/json",
                headers={"Upgrade": "websocket"},
                keep_alive=ka,
            )
        session = self._session(req)
        if self.login_required and session is None and not (req.path == "/api/stop" and req.method == "POST"):
            return _error(401, "unauthenticated", f"{req.path}: log in first (POST /api/login)", ka)
        if req.path in ("/api/state", "/api/info") and req.method != "GET":  # not "unknown API key" (a trial)
            return _error(405, "bad_request", f"use GET for {req.path}", ka)
        if req.path == "/api/state" and req.method == "GET":
            if self._state is None:
                return _error(503, "unavailable", "the service has published no state yet", ka)
            return json_response(200, json_safe(self._state), keep_alive=ka)
        if req.path in ("/api/view", "/api/terminal"):
            return self._view_route(req)
        if req.path == "/api/info" and req.method == "GET":
            info = dict(self.info)
            if session is not None:
                info.update(user=session.user, role=session.role)
            return json_response(200, json_safe(info), keep_alive=ka)
        if not req.path.startswith("/api/"):
            return _error(404, "not_found", f"nothing at {req.path!r}", ka)
        name = req.path[len("/api/") :]
        if not API_NAME.match(name):
            return _error(404, "unknown_key", f"unknown API path {req.path!r}", ka)
        if req.method != "POST":
            if self.api_keys is not None and name not in self.api_keys:  # "use POST" only for a key POST reaches
                return _error(404, "unknown_key", f"unknown API key {name!r}: nothing at {req.path!r}", ka)
            return _error(405, "bad_request", f"use POST for /api/{name}", ka)
        ctype = req.header("content-type").split(";")[0].strip().lower()
        if req.body and ctype != "application/json" and name != "stop":  # whatever is sent to stop, stops
            return _error(415, "bad_request", "send the request body with Content-Type: application/json", ka)
        if session is not None and name != "stop" and not session.csrf_ok(req.header("x-csrf-token")):
            return _error(403, "forbidden", f"{name}: missing or wrong X-CSRF-Token header (from the login)", ka)
        user = session.user if session is not None else (None if self.login_required else self.settings.user)
        ok, reply = await self._call(name, req.body, user)
        status = 200 if ok else ERROR_STATUS.get(str(reply.get("error")), 400)
        return json_response(status, json_safe(reply), keep_alive=ka)

    async def _call(self, name: str, body: bytes, user: str | None, received: float | None = None) -> tuple[bool, dict]:
        """One request, stamped with its arrival now (its ``deadline_ms`` counts from then, and a stop sent
        after it cancels it: time spent queueing is not forgiven). ``stop`` on its own thread, so it never
        waits behind other requests; the rest through the service's lanes (``dispatch``) or, without them,
        on this server's worker threads (the handler may plan for tens of milliseconds)."""
        received = time.monotonic() if received is None else received  # a WebSocket command: when its message came
        loop = asyncio.get_running_loop()
        try:
            if self._dispatch is not None and name != "stop":
                answered: asyncio.Future[tuple[bool, bytes]] = loop.create_future()

                def respond(ok: bool, data: bytes) -> None:
                    try:
                        loop.call_soon_threadsafe(_settle, answered, ok, data)
                    except RuntimeError:  # the loop closed meanwhile: nobody waits for the answer
                        pass

                self._dispatch(name, body, respond, received=received, user=user, inline=self._pool)
                ok, data = await answered
                reply = json.loads(data)
            else:
                pool = self._stop_pool if name == "stop" else self._pool
                call = functools.partial(self.handler, name, body, user, received=received)
                ok, reply = await loop.run_in_executor(pool, call)
        except Exception as exc:  # noqa: BLE001 — the handler promises not to raise; never trust it blindly
            log.exception("handler raised for %s", name)
            return False, {"error": "internal", "message": f"{name}: internal error {type(exc).__name__}"}
        if not isinstance(reply, dict):
            return False, {"error": "internal", "message": f"{name}: handler returned {type(reply).__name__}"}
        return bool(ok), reply

    # ------------------------------------------------------------------ WebSocket
    async def _websocket(self, req: HttpRequest, reader, writer) -> None:
        refusal = self._check(req)
        try:
            if refusal is None and (req.method != "GET" or req.header("sec-websocket-version") != "13"):
                raise WebSocketError("a WebSocket needs GET with Sec-WebSocket-Version: 13")
            accept = accept_key(req.header("sec-websocket-key")) if refusal is None else ""
        except WebSocketError as exc:
            refusal = _error(400, "bad_request", str(exc), keep_alive=False)
        if refusal is not None:
            writer.write(refusal)
            await writer.drain()
            return
        writer.write(
            (
                "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Accept: {accept}\r\n\r\n"
            ).encode("ascii")
        )
        await writer.drain()
        session = self._session(req)  # None with a login: the hub closes the socket with 4401 (log in first)
        if session is not None or not self.login_required:
            self._want_view()
        await self._hub.serve(WebSocket(reader, writer), session, self.settings.user)


def attach_zenoh(session: Any, prefix: str, server: WebServer) -> tuple[Any, Any]:
    """Feed ``server`` from ``<prefix>/state`` and ``<prefix>/events`` on a Zenoh session.

    For a terminal outside the service process. Returns the two subscribers (undeclare them, or
    close the session, to stop). Samples that are not JSON objects are dropped.
    """

    def forward(publish: Callable[[dict], None]) -> Callable[[Any], None]:
        def cb(sample) -> None:
            try:
                data = json.loads(sample.payload.to_bytes())
            except (ValueError, AttributeError):
                return
            if isinstance(data, dict):
                publish(data)

        return cb

    return (
        session.declare_subscriber(f"{prefix}/state", forward(server.publish_state)),
        session.declare_subscriber(f"{prefix}/events", forward(server.publish_event)),
    )


def _role_of(policy: Any) -> Callable[[str], str | None]:
    """The role a user has under the service's access policy (duck-typed: ``operators``,
    ``viewers``); without a policy every authenticated user may do everything (an operator)."""
    if policy is None:
        return lambda _user: "operator"
    operators, viewers = tuple(getattr(policy, "operators", ())), tuple(getattr(policy, "viewers", ()))
    return lambda user: "operator" if user in operators else "viewer" if user in viewers else None


def _view_factory(config: Any) -> Callable[[], HitchView] | None:
    """The hitch picture of the service's profile, category and implement (its config, duck-typed);
    None when the config names no profile."""
    profile = getattr(config, "profile", None)
    if not isinstance(profile, str):
        return None
    category, implement = getattr(config, "category", None), getattr(config, "implement", None)
    return functools.partial(HitchView.build, profile, category, implement)


def start_http(
    service: Any,
    addr: str = "127.0.0.1:8080",
    *,
    user: str | None = None,
    extra_hosts: tuple[str, ...] = (),
    users: Mapping[str, str] | None = None,
) -> WebServer:
    """Start the operator terminal of a running :class:`bridge.service.server.HitchService`.

    Commands go to ``service.api.handle``; state and events come from
    ``service.add_listener("state" | "event", …)`` (the dicts the service puts on Zenoh),
    or, without it, from the Zenoh publications through ``service.session`` (:func:`attach_zenoh`).

    ``users``: the ``user -> password`` dictionary of the service's security file. Given (not
    empty), the terminal has a login against it; roles come from the API's access policy
    (``service.api.policy``: operators move, viewers watch and stop; users in no role cannot log
    in; without a policy every user is an operator) and commands run as the logged-in user.
    ``user`` (``--http-user``) is then not used. When the API has an access policy but no
    ``users`` are given, :class:`WebServerError` (a ``ValueError``): a terminal without a login
    would let anyone who opens the page act as one fixed user. Without access control and
    ``users`` there is no login; commands run as ``user`` (normally None). Returns the started
    :class:`WebServer`; ``close()`` it before the service.
    """
    api = getattr(service, "api", None) or service
    handler = getattr(api, "handle", None)
    if not callable(handler):
        raise WebServerError("service has no API handler (expected service.api.handle(key, payload, user))")
    policy = getattr(api, "policy", None)
    accounts: Accounts | None = None
    if users:
        accounts = Accounts(users, _role_of(policy))
        if user is not None:
            log.warning("http_user %r is not used: the operator terminal has a login (access control is on)", user)
            user = None
    elif policy is not None:
        raise WebServerError(
            "http login: the service has an access policy, so the operator terminal needs a login against the "
            "user/password file of the security file (transport/auth/usrpwd/dictionary_file); http_user alone "
            "would let anyone who opens the page act as that user"
        )
    host, port = parse_address(addr)
    config = getattr(service, "config", None)
    if getattr(config, "security", None) is not None and policy is None:
        log.warning(
            "the service runs with a Zenoh security config but its API has no access policy: the "
            "operator terminal's commands are not checked against the access-control list"
        )
    prefix = getattr(config, "prefix", None)
    dispatch = getattr(service, "dispatch", None) if service is not api else None
    server = WebServer(
        handler,
        WebSettings(host=host, port=port, user=user, extra_hosts=tuple(extra_hosts)),
        info={"prefix": prefix},
        accounts=accounts,
        view=_view_factory(config),
        dispatch=dispatch if callable(dispatch) else None,
        api_keys=getattr(api, "api_keys", None),
    ).start()

    def on_login(what: str, who: str | None, ok: bool, reply: dict) -> None:
        hook = getattr(api, "on_request", None)  # the black box attaches after the service started: read it now
        if callable(hook):
            hook(what, who, None, ok, reply)

    server.on_login = on_login
    try:
        if callable(getattr(service, "add_listener", None)):
            for kind, fn in (("state", server.publish_state), ("event", server.publish_event)):
                service.add_listener(kind, fn)
                if callable(getattr(service, "remove_listener", None)):
                    server.add_close_hook(functools.partial(service.remove_listener, kind, fn))
        elif getattr(service, "session", None) is not None and prefix is not None:
            for sub in attach_zenoh(service.session, prefix, server):
                server.add_close_hook(sub.undeclare)
        else:
            raise WebServerError(
                "service offers neither add_listener() nor a Zenoh session: the page would show no state"
            )
    except Exception:
        server.close()
        raise
    return server
