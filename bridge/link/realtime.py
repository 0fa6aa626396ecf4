"""Running a CAN node in real time: opening a python-can bus and the loop that polls a node.

:class:`RealtimeRunner` drives any :class:`BusNode` (the planner-side
:class:`~bridge.link.can_link.CanLink`, or a simulated ECU node) on a background thread:
poll the node, block on ``bus.recv`` until its next deadline, hand over a frame, repeat.
No busy loop; node time is ``clock() - t0`` with t0 taken at :meth:`RealtimeRunner.start`.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol
from urllib.parse import urlsplit

import can

from bridge.link.state import LinkError
from bridge.link.stop_signal import StopSignal
from bridge.link.virtual import InProcessBus

__all__ = [
    "BusNode",
    "BusPort",
    "INTERFACES",
    "ReceivingNode",
    "RealtimeRunner",
    "SharedBusNodes",
    "open_bus",
    "shutdown_bus",
    "waiting_reader",
]

INTERFACES = ("udp_multicast", "socketcan", "virtual", "remote")
"""python-can interfaces the bridge runs on (virtual: in-process only; remote: processes on
this computer through a :class:`~bridge.link.loopback.LoopbackHub` on 127.0.0.1)."""


def open_bus(interface: str, channel: str | None = None, **kwargs: Any) -> can.BusABC:
    """Open a python-can bus on one of :data:`INTERFACES`.

    ``channel`` defaults to python-can's default IPv4 group for ``udp_multicast``,
    ``vcan0`` for ``socketcan``, ``hitch`` for ``virtual`` (an :class:`~bridge.link.virtual.InProcessBus`:
    python-can's virtual bus with a cheaper frame copy) and the default hub
    ``ws://127.0.0.1:54701/`` for ``remote`` (a :class:`~bridge.link.loopback.LoopbackHub`
    must be running there). udp_multicast delivers
    our own frames back: the link and the ECU node drop frames from their own address.
    ``kwargs`` go to :class:`can.Bus` as they are (interface-specific options).
    """
    if interface not in INTERFACES:
        raise LinkError(f"interface must be one of {', '.join(INTERFACES)}, got {interface!r}")
    if channel is None:
        if interface == "udp_multicast":
            from can.interfaces.udp_multicast import UdpMulticastBus

            channel = UdpMulticastBus.DEFAULT_GROUP_IPv4
        elif interface == "remote":
            from bridge.link.loopback import hub_url

            channel = hub_url()
        else:
            channel = "vcan0" if interface == "socketcan" else "hitch"
    try:
        if interface == "virtual":  # python-can's virtual bus with a field-by-field frame copy (bridge.link.virtual)
            return InProcessBus(channel=channel, **kwargs)
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except (can.CanError, OSError, ImportError) as exc:
        port = urlsplit(channel).port if interface == "remote" and isinstance(channel, str) else None
        hint = (
            f" (no hub there: start one with `hitch can-hub{f' --port {port}' if port else ''}`, or give the hub's "
            "URL as the channel)"
            if interface == "remote" and isinstance(exc, ConnectionRefusedError)
            else ""
        )
        raise LinkError(f"cannot open {interface} channel {channel!r}: {exc}{hint}") from None


def shutdown_bus(bus: can.BusABC) -> BaseException | None:
    """Shut ``bus`` down; a bus whose other end went away (a killed CAN hub: python-can-remote's shutdown
    raises ``OSError`` [Errno 107] on its dead socket, or its ``WebsocketClosed``) is returned as the
    exception, not raised, and counts as shut down (python-can would otherwise try again, with a traceback,
    when the object is collected)."""
    try:
        bus.shutdown()
    except Exception as exc:  # noqa: BLE001 (whatever the interface raises for a dead connection: returned)
        bus._is_shutdown = True  # noqa: SLF001 (python-can's own flag: its __del__ would shut it down again)
        return exc
    return None


class BusNode(Protocol):
    """What :class:`RealtimeRunner` drives: a :class:`~bridge.link.can_link.CanLink` or an ECU node."""

    @property
    def bus(self) -> can.BusABC: ...

    def start(self, now_s: float) -> None: ...

    def poll(self, now_s: float) -> None: ...

    def handle(self, frame: can.Message, now_s: float) -> None: ...

    def next_due_s(self) -> float: ...


class ReceivingNode:
    """The :class:`BusNode` side of a node that only listens: :meth:`poll` takes every frame waiting
    on its bus and :meth:`handle` the frame the runner received, both through the subclass's
    ``take(frame, now_s)``; the node is due :attr:`poll_period_s` after the last frame or poll.
    A subclass sets ``_bus`` and ``_now`` (the time of the last frame or poll)."""

    poll_period_s: float = 0.05
    _bus: can.BusABC
    _now: float

    @property
    def bus(self) -> can.BusABC:
        return self._bus

    def start(self, now_s: float) -> None:
        self._now = now_s

    def next_due_s(self) -> float:
        return self._now + self.poll_period_s

    def poll(self, now_s: float) -> None:
        self._now = now_s
        while (frame := self._bus.recv(timeout=0.0)) is not None:
            self.take(frame, now_s)

    def handle(self, frame: can.Message, now_s: float) -> None:
        self.take(frame, now_s)

    def take(self, frame: can.Message, now_s: float) -> object:
        """Take one frame at ``now_s`` (the subclass's decoding); its result is the subclass's."""
        raise NotImplementedError


#: frames a runner hands over before it polls its node again. Every frame that waited in the bus goes
#: first: a node judges silence by read time (the link's ECU heartbeat, its measurements), so a poll
#: between two parts of a backlog finds the next heartbeat "missing" although it is waiting (after a
#: 0.45 s stall of the link's thread, a cap of 32 raised a false ecu_heartbeat). 1024 frames hold over
#: 2 s of the planner bus's traffic at rest (about 380 frames/s) and take some tens of ms to hand over; the
#: bound only keeps a sender faster than its node from postponing the node's deadlines for ever.
_DRAIN_MAX = 1024


class RealtimeRunner:
    """Runs a :class:`BusNode` in real time on a background thread.

    The thread polls the node, then blocks on ``bus.recv`` until the node's next
    deadline (at most ``max_wait_s``), hands over that frame and every frame already
    waiting behind it (at most :data:`_DRAIN_MAX`: a backlog left by a stall is read
    before the node judges anything again), and repeats: no busy loop, and one poll per
    wake-up rather than one per frame (two frames sent together cost one pass over the node).
    Node time is ``clock() − t0``, t0 taken at :meth:`start`.

    ``prompt`` (default: always) says whether the node needs its frames as they arrive. While it
    returns False the thread does not wake for frames: it sleeps until the node is due and then
    hands over every frame that arrived meanwhile, read at that time (the frames keep their bus
    stamps). A node at rest that reads the bus only to judge it at its own deadlines (the planner's
    link while no reference streams) then costs one wake-up per deadline instead of one per frame
    burst. A change of ``prompt`` takes effect at the next wake-up, at most one deadline (or
    ``max_wait_s``) later.
    """

    def __init__(
        self,
        node: BusNode,
        *,
        clock: Callable[[], float] = time.monotonic,
        max_wait_s: float = 0.05,
        name: str | None = None,
        prompt: Callable[[], bool] | None = None,
    ) -> None:
        if not 0.0 < max_wait_s <= 1.0:
            raise LinkError(f"max_wait_s must lie in (0, 1] s, got {max_wait_s!r}")
        self._node = node
        self._clock = clock
        self._max_wait_s = float(max_wait_s)
        self._t0 = clock()
        self._stop = StopSignal()  # a timed wait of one lock acquire (stop_signal)
        self._thread: threading.Thread | None = None
        self._name = name or f"{type(node).__name__}-rt"
        self._prompt = prompt
        self.error: BaseException | None = None
        """The exception that ended the loop, if any."""

    def now(self) -> float:
        """Node time, s."""
        return self._clock() - self._t0

    def start(self) -> RealtimeRunner:
        """Start the node at time 0, then the thread."""
        if self._thread is not None:
            raise LinkError("runner already started")
        self._t0 = self._clock()
        self._node.start(0.0)
        self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        """Ask the thread to end and wait for it."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def wait(self, duration_s: float) -> bool:
        """Sleep up to ``duration_s`` or until the loop ends; True if it ended."""
        return self._stop.wait(duration_s)

    def _run(self) -> None:
        node = self._node
        try:
            prompt, take = self._prompt, waiting_reader(node.bus)
            while not self._stop.is_set():
                node.poll(self.now())
                wait = min(max(node.next_due_s() - self.now(), 0.0), self._max_wait_s)
                if prompt is None or prompt():
                    frame = node.bus.recv(timeout=wait)  # woken by the first frame
                elif self._stop.wait(wait):
                    break
                else:  # due: what arrived meanwhile, then the poll
                    frame = take()
                if frame is None:
                    continue
                now, taken = self.now(), 0
                while frame is not None:  # every frame already waiting, then one poll (not one per frame)
                    node.handle(frame, now)
                    taken += 1
                    frame = take() if taken < _DRAIN_MAX else None
        except BaseException as exc:  # handed to the owner, never lost
            self.error = exc
            self._stop.set()

    def __enter__(self) -> RealtimeRunner:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def waiting_reader(bus: can.BusABC) -> Callable[[], can.Message | None]:
    """A function returning the next frame already waiting on ``bus`` that passes its receive filters, or None
    when none waits; the read path is chosen once for the bus (a runner reads every frame through it).

    python-can's ``recv(timeout=0.0)`` returns None at the first waiting frame its software filters reject
    (the virtual and udp_multicast buses filter in Python), even with wanted frames behind it: a loop that
    drains with it at its deadlines would take one such frame per deadline and fall behind the bus. The
    reader goes past them (python-can's own receive path: ``_recv_internal``, then ``_matches_filters``). A
    bus that receives its own way (it overrides ``recv``: python-can-remote's client, a :class:`BusPort`) is
    read through its ``recv``."""
    if type(bus).recv is not can.BusABC.recv:
        return lambda: bus.recv(timeout=0.0)

    def take() -> can.Message | None:
        while True:
            msg, already_filtered = bus._recv_internal(timeout=0.0)
            if msg is None:
                return None
            if already_filtered or bus._matches_filters(msg):
                return msg

    return take


class BusPort(can.BusABC):
    """One node's side of a bus it shares with the other nodes of one runner (:class:`SharedBusNodes`).

    Sends go to the shared bus. What the shared bus receives, the runner delivers into every port
    (:meth:`deliver`), and the node reads it from its port as from a bus of its own — through
    whatever it wraps the port in (the simulated ECU's fault injector cuts, delays and loses frames
    there). Shutting a port down leaves the shared bus open (its owner shuts it down).
    """

    def __init__(self, shared: can.BusABC) -> None:
        self._shared = shared
        self._inbox: deque[can.Message] = deque()
        super().__init__(channel=shared.channel_info)
        self._is_shutdown = True  # a port holds nothing to release (python-can warns about open buses)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._shared.send(msg, timeout)

    def deliver(self, msg: can.Message) -> None:
        """A frame the shared bus received (any thread)."""
        self._inbox.append(msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next delivered frame, or None at once (a port never blocks: the runner waits on the shared
        bus). Without receive filters of its own, straight from the inbox (python-can's generic ``recv``
        would log and filter-check every frame the shared bus already filtered)."""
        if self.filters:
            return super().recv(timeout)
        try:
            return self._inbox.popleft()
        except IndexError:
            return None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            return self._inbox.popleft(), False
        except IndexError:  # nothing waiting; the runner polls the node again after the next frame
            return None, False


class SharedBusNodes:
    """Several nodes on one bus, run by one :class:`RealtimeRunner` (a :class:`BusNode`).

    Each node is built on a :meth:`port` of the shared bus and then :meth:`add`-ed. Every received
    frame is delivered into every port; the runner polls the nodes right after, and each node reads
    its port in its ``poll`` as it reads a bus of its own. One bus instead of one per node: on a
    python-can ``virtual`` channel every frame is copied into every bus's queue and wakes its
    thread, so fewer buses cost less per frame (the machine twin and the planner each use one).
    """

    def __init__(self, bus: can.BusABC) -> None:
        self._bus = bus
        self.nodes: list[BusNode] = []
        self._ports: list[BusPort] = []

    def port(self) -> BusPort:
        """A new port of the shared bus for a node."""
        p = BusPort(self._bus)
        self._ports.append(p)
        return p

    def add(self, node: BusNode) -> SharedBusNodes:
        """Run ``node`` (built on one of this bus's ports)."""
        self.nodes.append(node)
        return self

    @property
    def bus(self) -> can.BusABC:
        return self._bus

    def start(self, now_s: float) -> None:
        if not self.nodes:
            raise LinkError("SharedBusNodes has no node to run")
        for n in self.nodes:
            n.start(now_s)

    def poll(self, now_s: float) -> None:
        for n in self.nodes:
            n.poll(now_s)

    def handle(self, frame: can.Message, now_s: float) -> None:
        """Deliver ``frame`` into every port; the nodes read it at their next poll (the runner polls at once)."""
        for p in self._ports:
            p.deliver(frame)

    def next_due_s(self) -> float:
        return min(n.next_due_s() for n in self.nodes)
