"""The CAN hub's clients leave cleanly, however their connection ends (bridge.link.loopback)."""

from __future__ import annotations

import json
import threading
import uuid

import can
import pytest
from can.interfaces import virtual

from bridge.link.loopback import LoopbackHub, _hub_server_class


class _VanishingClientSocket:
    """A client's WebSocket as the hub sees it when the client process is killed while frames flow:
    the bus request arrives, the hub's answer goes out, the next frame sent to it meets a broken pipe,
    the read side then sees the reset, and closing fails (the connection is already gone)."""

    protocol = "can.json.v1"

    def __init__(self) -> None:
        self._events = [json.dumps({"type": "bus_request", "payload": {"config": {}}})]
        self._sent = 0
        self.gone = threading.Event()

    def wait(self, timeout: float | None = None) -> bool:
        if self._events:
            return True
        if not self.gone.wait(5.0 if timeout is None else timeout):
            return False
        raise ConnectionResetError(104, "Connection reset by peer")

    def read(self) -> str:
        return self._events.pop(0)

    def send(self, payload: object) -> None:
        self._sent += 1
        if self._sent > 1:  # the first is the hub's bus_response
            self.gone.set()
            raise BrokenPipeError(32, "Broken pipe")

    def close(self, *args: object) -> None:
        raise OSError(107, "Transport endpoint is not connected")


def _queues(channel: str) -> int:
    return len(virtual.channels.get(channel, []))


def _run_vanishing_client(protocol_class: type, channel: str) -> tuple[BaseException | None, list[str]]:
    """One client link on ``channel`` that vanishes on the first frame; (what ``run`` raised, the
    names of threads that died with an exception)."""
    died: list[str] = []
    hook = threading.excepthook
    threading.excepthook = lambda a: died.append(a.thread.name if a.thread else "?")
    link = None
    try:
        with can.Bus(interface="virtual", channel=channel) as other:
            link = protocol_class({"interface": "virtual", "channel": channel}, _VanishingClientSocket())
            assert _queues(channel) == 2
            other.send(can.Message(arbitration_id=0x18FF2100, data=bytes(8), is_extended_id=True))
            raised: BaseException | None = None
            try:
                link.run()
            except BaseException as exc:  # noqa: BLE001 - what the old protocol let out
                raised = exc
            link._send_thread.join(2.0)
            for _ in range(20):  # frames sent after the client vanished
                other.send(can.Message(arbitration_id=0x18FF2100, data=bytes(8), is_extended_id=True))
            leaked = _queues(channel) - 1
            assert leaked == 0, f"the vanished client's bus is still on the channel ({leaked} queue; frames pile up)"
    finally:
        threading.excepthook = hook
        if link is not None:
            link.bus.shutdown()  # what the old protocol left behind (idempotent)
    return raised, died


def test_a_client_that_vanishes_while_frames_flow_leaves_no_bus_behind():
    """Defect (seen in the reliability bench's CPU scenario): with python-can-remote's own protocol the
    sender thread died on the broken pipe without shutting its bus down; every later frame of the
    hub's channel piled up in that bus's queue (26 094 frames a second after a killed ECU process),
    and two tracebacks went to stderr. The hub's protocol shuts the bus down and raises nothing."""
    raised, died = _run_vanishing_client(_hub_server_class().protocol_class, f"hub-test-{uuid.uuid4().hex}")
    assert raised is None and died == []


def test_the_librarys_own_protocol_leaks_the_bus_there():
    """The reproduction above against python-can-remote's protocol itself: it fails there (a check
    that the fake client really takes the path that leaked)."""
    from can_remote.server import RemoteServerProtocol

    with pytest.raises(AssertionError, match="still on the channel"):
        _run_vanishing_client(RemoteServerProtocol, f"hub-test-{uuid.uuid4().hex}")


def test_the_hub_serves_frames_between_two_clients():
    with LoopbackHub() as hub:
        with can.Bus(interface="remote", channel=hub.url) as a, can.Bus(interface="remote", channel=hub.url) as b:
            a.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
            got = b.recv(5.0)
            assert got is not None and got.arbitration_id == 0x123 and bytes(got.data) == b"\x01\x02"
            assert a.recv(0.2) is None  # never the sender itself
