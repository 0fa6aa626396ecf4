"""The real-time runner reads every frame that waited in the bus before it polls its node again.

The old defect: after a stall of the runner's thread the frames that had queued were handed over 32 at
a time with a poll of the node after each 32. A link's poll judges silence by read time, so it found
the ECU's next heartbeat (still unread, behind the first 32 frames) missing and raised a false
``ecu_heartbeat`` (seen under CPU load in ``test_machine_faults``' stall test: 3 of 8 runs)."""

from __future__ import annotations

import threading
import time
import uuid

import can

from bridge.link.realtime import RealtimeRunner, open_bus


class _RecordingNode:
    """A node that records how many frames it had been handed at each poll; its poll can be held."""

    def __init__(self, bus: can.BusABC) -> None:
        self._bus = bus
        self.handled = 0
        self.polls: list[int] = []
        self.hold = threading.Event()  # set: the next poll blocks until release is set
        self.held = threading.Event()
        self.release = threading.Event()

    @property
    def bus(self) -> can.BusABC:
        return self._bus

    def start(self, now_s: float) -> None:
        pass

    def poll(self, now_s: float) -> None:
        self.polls.append(self.handled)
        if self.hold.is_set():
            self.hold.clear()
            self.held.set()
            self.release.wait(5.0)

    def handle(self, frame: can.Message, now_s: float) -> None:
        self.handled += 1

    def next_due_s(self) -> float:
        return 1e9  # never due: the runner waits for frames (at most max_wait_s)


def test_after_a_stall_every_waiting_frame_is_handed_over_before_the_next_poll():
    ch = f"rt-{uuid.uuid4().hex}"
    bus, sender = open_bus("virtual", ch), open_bus("virtual", ch)
    node = _RecordingNode(bus)
    runner = RealtimeRunner(node, max_wait_s=0.01).start()
    try:
        node.hold.set()
        assert node.held.wait(5.0), "the runner never polled"
        n = 400  # about a second of the planner bus's traffic at rest
        for k in range(n):
            sender.send(can.Message(arbitration_id=0x0CFF22A9, data=[k % 256] * 8, is_extended_id=True))
        polls_before = len(node.polls)
        node.release.set()
        deadline = time.monotonic() + 5.0
        while node.handled < n and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.05)  # the poll after the backlog
        assert node.handled == n
        after = node.polls[polls_before:]
        assert after and after[0] == n, f"polled after {after[:5]} of {n} waiting frames"
    finally:
        runner.stop()
        bus.shutdown()
        sender.shutdown()
    assert runner.error is None
