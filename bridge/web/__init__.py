"""The operator terminal in the browser: the thesis's virtual terminal as a web page.

``hitch serve --http 127.0.0.1:8080`` serves one page and a small HTTP/WebSocket API from the
service process; the page shows what ``<prefix>/state`` publishes and sends commands through the
service's own API handler. Modules, one concept each:

* :mod:`.server`    — :class:`~.server.WebServer` and :func:`~.server.start_http` (the hook the
  service calls), :func:`~.server.attach_zenoh`;
* :mod:`.hub`       — the WebSocket sessions: state/event fan-out, commands in;
* :mod:`.view`      — :class:`~.view.HitchView`, the hitch picture's numbers (the model's points
  for the measured and the target actuators);
* :mod:`.wording`   — the operator words of the service's limit codes (pure tables);
* :mod:`.settings`  — :class:`~.settings.WebSettings`, address parsing, Host/Origin checks;
* :mod:`.http`      — a minimal HTTP/1.1 reader and writer on asyncio streams;
* :mod:`.websocket` — RFC 6455 framing and handshake;
* ``static/``       — ``index.html``, ``app.js``, ``style.css`` (no build step).

The names below load lazily (PEP 562): this package file imports nothing, so importing the
service does not load the web server.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from bridge.web.http import HttpError, HttpRequest
    from bridge.web.hub import ClientHub, CommandError
    from bridge.web.server import (
        BindTimeout,
        Dispatch,
        Handler,
        WebServer,
        WebServerError,
        WebServerStateError,
        attach_zenoh,
        start_http,
    )
    from bridge.web.settings import WebSettings, WebSettingsError, parse_address
    from bridge.web.view import VIEW_RATE_HZ, HitchView, limit_codes
    from bridge.web.websocket import WebSocket, WebSocketError
    from bridge.web.wording import limited_words, words

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(
        (
            "WebServer",
            "WebServerError",
            "WebServerStateError",
            "BindTimeout",
            "Handler",
            "Dispatch",
            "attach_zenoh",
            "start_http",
        ),
        "bridge.web.server",
    ),
    **dict.fromkeys(("ClientHub", "CommandError"), "bridge.web.hub"),
    **dict.fromkeys(("WebSettings", "WebSettingsError", "parse_address"), "bridge.web.settings"),
    **dict.fromkeys(("HttpError", "HttpRequest"), "bridge.web.http"),
    **dict.fromkeys(("HitchView", "VIEW_RATE_HZ", "limit_codes"), "bridge.web.view"),
    **dict.fromkeys(("words", "limited_words"), "bridge.web.wording"),
    **dict.fromkeys(("WebSocket", "WebSocketError"), "bridge.web.websocket"),
}

__all__ = [
    # the server (bridge.web.server)
    "WebServer",
    "WebServerError",
    "WebServerStateError",
    "BindTimeout",
    "Handler",
    "Dispatch",
    "attach_zenoh",
    "start_http",
    # the WebSocket sessions (bridge.web.hub)
    "ClientHub",
    "CommandError",
    # settings and request checks (bridge.web.settings)
    "WebSettings",
    "WebSettingsError",
    "parse_address",
    # HTTP (bridge.web.http)
    "HttpError",
    "HttpRequest",
    # WebSocket framing (bridge.web.websocket)
    "WebSocket",
    "WebSocketError",
    # the hitch picture (bridge.web.view) and the limit words (bridge.web.wording)
    "HitchView",
    "VIEW_RATE_HZ",
    "limit_codes",
    "words",
    "limited_words",
]


if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(__name__, globals(), _SOURCES)
