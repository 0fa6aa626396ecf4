"""The planner's CAN runner at rest (as :func:`start_can` builds it) wakes for the link's checks, once a
control period, not for every frame burst of the ECU and the tractor; while changing references stream
it wakes for frames as they arrive; holding a pose after a move (the link re-sends the last reference)
is at rest again, for the link's runner and the twin's.

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
from bridge.service.machine import start_can
from tests.helpers import goto_when_ready, running_machine, wait_until

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
    with running_machine("idle") as (cfg, parts, mc, _):
        link = parts.link
        # a slow move: still streaming for the whole window
        assert goto_when_ready(mc, {"z": 0.3}, speed_scale=0.1), "the link never became ready"
        assert wait_until(lambda: link.streaming, 2.0)
        polls = _count_polls(link)
        time.sleep(0.5)
        assert link.streaming, link.faults.reasons
        window = polls[-1] - polls[0]
        # the ECU sends at 100 Hz: woken by its frames, more than once a control period
        assert len(polls) - 1 > 1.5 * window * cfg.control_rate, f"{len(polls) - 1} polls in {window:.3f} s"


def test_holding_a_pose_after_a_move_wakes_both_runners_at_their_deadlines_only():
    """After a goto the controller holds the pose and the link keeps re-sending its reference (the ECU's
    watchdog stays fed). Nothing changes then, so neither runner needs frames as they arrive: the link's
    is polled about once a control period (its reference slots), the twin's at its 10 ms ticks. Before,
    both stayed prompt for as long as the pose was held (link: about 150 polls a second; planner side
    6.3 % of a core instead of 3.8–4.6 % in the idle bench, ``docs/benchmarks.md``)."""
    with running_machine("idle") as (cfg, parts, mc, events):
        link, ecu_node = parts.link, parts.ecu_node
        assert ecu_node is not None
        assert goto_when_ready(mc, {"z": 0.26}), "the link never became ready"
        finished = lambda: any(e.get("event") == "motion_finished" for e in events)  # noqa: E731
        assert wait_until(lambda: finished() and link.holding, 20.0), [e.get("event") for e in events]
        assert ecu_node.ecu.fed and ecu_node.ecu.holding
        link_polls, twin_polls = _count_polls(link), _count_polls(ecu_node)
        sent = link.counters.references_tx
        time.sleep(1.0)
        assert link.streaming and link.holding and not link.faults.any, link.faults.reasons
        window = link_polls[-1] - link_polls[0]
        period = 1.0 / cfg.control_rate
        assert len(link_polls) - 1 <= window / period + 3, f"{len(link_polls) - 1} link polls in {window:.3f} s"
        assert link.counters.references_tx - sent >= 0.8 * cfg.control_rate  # the pose is still held
        window = twin_polls[-1] - twin_polls[0]
        assert len(twin_polls) - 1 <= window / 0.01 + 3, f"{len(twin_polls) - 1} twin polls in {window:.3f} s"
