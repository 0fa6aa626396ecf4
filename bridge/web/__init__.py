"""The operator terminal in the browser (issue 9): the thesis's virtual terminal as a web page.

``hitch serve --http 127.0.0.1:8080`` serves one page and a small HTTP/WebSocket API from the
service process; the page shows what ``<prefix>/state`` publishes and sends commands through the
service's own API handler. Modules, one concept each:

* :mod:`.server`    — :class:`~.server.WebServer` and :func:`~.server.start_http` (the hook the
  service calls), :func:`~.server.attach_zenoh`;
* :mod:`.hub`       — the WebSocket sessions: state/event fan-out, commands in;
* :mod:`.settings`  — :class:`~.settings.WebSettings`, address parsing, Host/Origin checks;
* :mod:`.http`      — a minimal HTTP/1.1 reader and writer on asyncio streams;
* :mod:`.websocket` — RFC 6455 framing and handshake;
* ``static/``       — ``index.html``, ``app.js``, ``style.css`` (no build step).

This package file imports nothing, so importing the service does not load the web server.
"""

__all__: list[str] = []
