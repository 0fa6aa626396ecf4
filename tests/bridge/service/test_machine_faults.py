"""The machine side as the service builds it (one shared bus per runner): the twin's fault injection
still acts on what the simulated ECU receives and sends, and the link detects each one-way loss.

The old defect: with the ECU on a port of a shared bus, frames reached it past its fault injector,
so ``cut planner_to_ecu`` cut nothing — no fault, and the motion went on."""

from __future__ import annotations

import tempfile
import time
import uuid

import pytest

from bridge.service.config import ServiceConfig
from bridge.service.machine import start_can
from tests.helpers import goto_when_ready, running_machine, wait_until

pytestmark = pytest.mark.slow  # real time: a few seconds


@pytest.mark.parametrize("cut, fault", [("planner_to_ecu", "references_lost"), ("ecu_to_planner", "stale_measurement")])
def test_a_one_way_cut_in_the_twin_is_detected_and_stops_the_motion(cut, fault):
    with running_machine("machine") as (_, parts, mc, events):
        assert goto_when_ready(mc, {"z": 0.3}, speed_scale=0.3), "the link never became ready"
        time.sleep(0.5)
        assert parts.ecu_node is not None
        parts.ecu_node.apply_fault({"cut": cut})
        assert wait_until(lambda: fault in {f.name for f in mc.faults}, 1.0), (cut, [f.name for f in mc.faults])
        assert wait_until(lambda: any(e.get("event") == "motion_aborted" for e in events), 1.0)


def test_a_stall_of_the_links_thread_alone_raises_no_ecu_heartbeat_fault():
    """The link's thread stalls for 0.45 s (here: its lock is held, as a long GIL or scheduler stall
    would hold the thread) while the twin's ECU keeps its 100 ms heartbeat. The heartbeats wait in
    the bus and are read together; their bus timestamps keep their spacing, so the ECU was on time.
    Before, the link judged the gap by read time alone and raised ``ecu_heartbeat`` (a false fault)."""
    cfg = ServiceConfig(data_dir=tempfile.mkdtemp(), can_channel=f"machine-{uuid.uuid4().hex}")
    parts = start_can(cfg)
    try:
        link = parts.link
        assert wait_until(lambda: link.claimed and link.status(parts.clock()).state is not None, 10.0)
        time.sleep(0.5)
        assert not link.faults.any, link.faults.reasons
        with link._lock:  # the stall: the runner blocks on its next poll
            time.sleep(0.45)
        time.sleep(0.3)
        assert not link.faults.ecu_heartbeat, link.faults.reasons
        assert not link.faults.any, link.faults.reasons
    finally:
        parts.close()
