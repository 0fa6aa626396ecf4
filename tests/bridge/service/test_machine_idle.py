"""The planner's CAN runner at rest (as :func:`start_can` builds it) wakes for the link's checks, once a
control period, not for every frame burst of the ECU and the tractor; while references stream it wakes
for frames as they arrive.

The old cost: at rest the runner polled after each of the twin's frame bursts and at least every 10 ms,
130–190 times a second, each wake-up costing a few hundred microseconds of CPU on the shared test
machine (``docs/benchmarks.md``, idle cost). Reading the frames together at a deadline must not be taken
for dropped frames (their bus stamps keep their spacing)."""

from __future__ import annotations

import tempfile
import time
import uuid

import pytest

from bridge.service.config import ServiceConfig
from bridge.service.machine import build_controller, start_can
from bridge.service.motion.types import MotionError
from tests.helpers import wait_until

pytestmark = pytest.mark.slow  # real time: a few seconds


def _count_polls(node) -> list[float]:
    """Wrap a node's poll (its runner polls it once per wake-up) to record each poll's time."""
    times: list[float] = []
    poll = node.poll

    def counted(now_s: float) -> None:
        times.append(now_s)
        poll(now_s)

    node.poll = counted
    return times


def test_at_rest_the_link_is_polled_once_a_control_period_and_counts_no_dropped_frames():
    cfg = ServiceConfig(data_dir=tempfile.mkdtemp(), can_channel=f"idle-{uuid.uuid4().hex}")
    parts = start_can(cfg)
    try:
        link = parts.link
        assert wait_until(lambda: link.claimed and link.status(parts.clock()).state is not None, 10.0)
        time.sleep(0.3)
        polls = _count_polls(link)
        before = link.counters
        time.sleep(1.0)
        window = polls[-1] - polls[0]
        n = len(polls) - 1
        after = link.counters
        period = 1.0 / cfg.control_rate
        assert n <= window / period + 2, f"{n} polls in {window:.3f} s: woken by frames"
        assert after.measurements_rx - before.measurements_rx >= 50  # the ECU's frames were all read
        # read 2 at a time, they were counted as one gap a read (about 50) from read times; a twin thread
        # late on a loaded machine may really skip a slot or two
        assert after.dropped_measurements - before.dropped_measurements <= 3
        assert after.dropped_hitch_status - before.dropped_hitch_status <= 3
        assert not link.faults.any, link.faults.reasons
        state = link.status(parts.clock()).state
        assert state is not None and parts.clock() - state.measurement_t_s <= cfg.stale_timeout_s
    finally:
        parts.close()


def test_at_rest_the_twins_runner_wakes_for_its_ticks_only():
    """The simulated ECU at rest (no reference feeding its watchdog) reads its bus at its 10 ms ticks, as an
    ECU's control task reads its mailbox: the planner's 10 Hz heartbeats no longer wake it between them
    (before: about 110 polls a second)."""
    cfg = ServiceConfig(data_dir=tempfile.mkdtemp(), can_channel=f"idle-{uuid.uuid4().hex}")
    parts = start_can(cfg)
    try:
        link, ecu_node = parts.link, parts.ecu_node
        assert ecu_node is not None
        assert wait_until(lambda: link.claimed and link.status(parts.clock()).state is not None, 10.0)
        time.sleep(0.3)
        assert not ecu_node.ecu.fed
        polls = _count_polls(ecu_node)
        time.sleep(1.0)
        window = polls[-1] - polls[0]
        assert len(polls) - 1 <= window / 0.01 + 3, f"{len(polls) - 1} polls in {window:.3f} s"
        assert not link.faults.any, link.faults.reasons
    finally:
        parts.close()


def test_while_references_stream_the_runner_wakes_for_the_ecus_frames():
    cfg = ServiceConfig(data_dir=tempfile.mkdtemp(), can_channel=f"idle-{uuid.uuid4().hex}")
    parts = start_can(cfg)
    mc, _ = build_controller(cfg, parts, on_state=lambda m: None, on_event=lambda e: None)
    mc.start()
    try:
        link = parts.link

        def started() -> bool:
            try:
                mc.goto({"z": 0.3}, speed_scale=0.1)  # a slow move: still streaming for the whole window
            except MotionError:  # not claimed / no measurement yet
                return False
            return True

        assert wait_until(started, 10.0), "the link never became ready"
        assert wait_until(lambda: link.streaming, 2.0)
        polls = _count_polls(link)
        time.sleep(0.5)
        assert link.streaming, link.faults.reasons
        window = polls[-1] - polls[0]
        # the ECU sends at 100 Hz: woken by its frames, more than once a control period
        assert len(polls) - 1 > 1.5 * window * cfg.control_rate, f"{len(polls) - 1} polls in {window:.3f} s"
    finally:
        mc.close()
        parts.close()
