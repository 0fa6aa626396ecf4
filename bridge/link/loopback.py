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

import threading
import uuid

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
        from can_remote.server import RemoteServer  # type: ignore[import-untyped]  # only where a hub runs

        channel = f"hitch-hub-{uuid.uuid4().hex}"
        try:
            self._server = RemoteServer(LOOPBACK_HOST, port, interface="virtual", channel=channel)
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
