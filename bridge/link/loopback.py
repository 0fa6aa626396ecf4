"""Cross-process CAN on loopback: a hub on 127.0.0.1 that several processes' buses share.

python-can's ``virtual`` bus reaches only its own process. For an ECU (real or simulated)
in another process on the same computer, without a CAN adapter and without sending to a
multicast group, :class:`LoopbackHub` serves one private ``virtual`` channel over
WebSocket on 127.0.0.1 (the server of the python-can-remote package). Every process opens
its bus with python-can's ``remote`` interface on the hub's URL (``open_bus("remote",
hub.url)``, ``hitch ecu-sim --interface remote --channel ws://127.0.0.1:PORT/``); a frame one
client sends reaches every other client, never the sender itself (like ``virtual``).

The hub listens on the loopback address only. ``hitch can-hub`` runs one as its own
process; a test or a service may run it in a thread of its own.
"""

from __future__ import annotations

import functools
import logging
import sys
import threading
import uuid
from typing import Any

from bridge.link.state import LinkError

__all__ = ["DEFAULT_HUB_PORT", "LOOPBACK_HOST", "LoopbackHub", "hub_url"]

#: The address a hub listens on and clients connect to.
LOOPBACK_HOST = "127.0.0.1"

#: The default TCP port of a hub (python-can-remote's default).
DEFAULT_HUB_PORT = 54701


def hub_url(port: int = DEFAULT_HUB_PORT) -> str:
    """The ``remote`` channel of a hub on this computer at ``port``."""
    return f"ws://{LOOPBACK_HOST}:{int(port)}/"


class LoopbackHub:
    """A CAN hub on 127.0.0.1: one private virtual channel shared by every ``remote`` client.

    Args:
        port: TCP port, 0 (default) for a free one chosen by the system; see :attr:`port`.
    """

    def __init__(self, port: int = 0) -> None:
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise LinkError(f"port must be an integer in 0..65535, got {port!r}")
        channel = f"hitch-hub-{uuid.uuid4().hex}"
        try:
            self._server = _hub_server_class()(LOOPBACK_HOST, port, interface="virtual", channel=channel)
        except OSError as exc:
            raise LinkError(f"cannot listen on {LOOPBACK_HOST}:{port}: {exc}") from None
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        """The TCP port the hub listens on."""
        return int(self._server.server_port)

    @property
    def url(self) -> str:
        """The channel clients open with the ``remote`` interface."""
        return hub_url(self.port)

    def start(self) -> LoopbackHub:
        """Serve clients on a background thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._server.serve_forever, name="can-hub", daemon=True)
            self._thread.start()
        return self

    def serve_forever(self) -> None:
        """Serve clients on this thread until :meth:`close` (from another thread) or Ctrl-C."""
        self._server.serve_forever()

    def close(self) -> None:
        """Stop serving and close the listening socket (connected clients see their bus close)."""
        if self._thread is not None:
            self._server.shutdown()
            self._thread.join(2.0)
            self._thread = None
        self._server.server_close()

    def __enter__(self) -> LoopbackHub:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


_log = logging.getLogger(__name__)


@functools.cache
def _hub_server_class() -> type:
    """python-can-remote's server with clients that always leave cleanly (built on first use: the
    package is imported only where a hub runs).

    The library's per-client sender thread died on a broken pipe when a client vanished while frames
    flowed (a killed ECU process): its bus was never shut down, so every later frame of the hub's
    channel queued up in it without bound (26 094 frames one second after such a kill, measured), and
    the thread's traceback, and the handler's, went to stderr. Here a client's bus is shut down
    however its connection ends, and a vanished client is one line of the log."""
    from can_remote.server import (  # type: ignore[import-untyped]
        ClientRequestHandler,
        RemoteServer,
        RemoteServerProtocol,
    )
    from can_remote.websocket import WebSocket, WebsocketClosed, get_accept_key  # type: ignore[import-untyped]

    class HubProtocol(RemoteServerProtocol):
        """One client's link: its virtual bus is shut down however the connection ends."""

        def _send_to_client(self) -> None:
            try:
                super()._send_to_client()
            except (OSError, WebsocketClosed) as exc:  # the client is gone
                self.running = False
                _log.info("CAN hub: a client went away while frames were sent to it (%s)", exc)
            finally:
                self.bus.shutdown()

        def run(self) -> None:
            try:
                super().run()
            except OSError as exc:  # closing a connection the client already dropped
                _log.info("CAN hub: a client's connection ended (%s)", exc)
            finally:  # (the library's run has stopped its sender thread, or waited 3 s for it)
                self.bus.shutdown()

    class HubRequestHandler(ClientRequestHandler):
        """The library's WebSocket upgrade (``ClientRequestHandler.start_websocket``, python-can-remote
        0.3.0) with :class:`HubProtocol`, and the client always removed from the server's list."""

        def start_websocket(self) -> None:
            self.send_response(101)
            self.send_header("Upgrade", "WebSocket")
            self.send_header("Connection", "Upgrade")
            self.send_header("Sec-WebSocket-Accept", get_accept_key(self.headers["Sec-WebSocket-Key"]))
            offered = [p.strip() for p in self.headers.get("Sec-WebSocket-Protocol", "can.json.v1").split(",")]
            protocol = "can.binary+json.v1" if "can.binary+json.v1" in offered else "can.json.v1"
            self.send_header("Sec-WebSocket-Protocol", protocol)
            self.end_headers()
            link = HubProtocol(self.server.config, WebSocket(None, protocol, sock=self.request))
            self.server.clients.append(link)
            try:
                link.run()
            finally:
                self.server.clients.remove(link)

    class HubServer(RemoteServer):
        protocol_class = HubProtocol  # (for tests)

        def __init__(self, host: str, port: int, **config: Any) -> None:
            super().__init__(host, port, **config)
            self.RequestHandlerClass = HubRequestHandler

        def handle_error(self, request: Any, client_address: Any) -> None:
            """One line for a client's failure, not a traceback on stderr (the hub goes on)."""
            _log.warning("CAN hub: client %s: %r", client_address, sys.exc_info()[1])

    return HubServer
