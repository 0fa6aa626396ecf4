"""Frames with the planner's own source address reach the link as the service builds it (``start_can``), whatever
their PGN, and raise ``address_conflict``; the link's own frames never come back to it, so none is a false one.

An integrator's finding: 94 spoofed 0x0CFF21A6 (PositionReference from 166) raised nothing, because the
planner bus's receive filter passed only the PGNs the link reads; a spoofed heartbeat from 166 did raise it."""

from __future__ import annotations

import contextlib
import tempfile
import time
import uuid
from collections.abc import Iterator
from typing import Any

import can
import pytest

from bridge.isobus.codec import load_codec
from bridge.link.loopback import LoopbackHub
from bridge.link.realtime import open_bus
from bridge.service.config import ServiceConfig
from bridge.service.machine import PLANNER_PGNS, build_controller, start_can
from tests.helpers import goto_when_ready, wait_until

pytestmark = pytest.mark.slow  # real time: a few seconds each

#: frames of the planner's own messages with its address 166, as another node would send them
_SPOOFS = {
    "PositionReference 0xFF21": 0x0CFF21A6,
    "EcuParameters 0xFF23": 0x18FF23A6,
    "MeasuredPose 0xFF25": 0x18FF25A6,
    "Heartbeat": 0x0CF0E4A6,
}


@contextlib.contextmanager
def _service_machine(interface: str, channel: str) -> Iterator[tuple[Any, Any]]:
    cfg = ServiceConfig(data_dir=tempfile.mkdtemp(), can_interface=interface, can_channel=channel)
    parts = start_can(cfg)
    try:
        mc, _ = build_controller(cfg, parts, on_state=lambda m: None, on_event=lambda e: None)
        mc.start()
        try:
            yield parts, mc
        finally:
            mc.close()
    finally:
        parts.close()


def _moves_without_a_false_conflict_then_sees_each_spoof(parts: Any, mc: Any, rival: can.BusABC) -> None:
    link = parts.link
    assert goto_when_ready(mc, {"z": 0.2}, speed_scale=0.5), "the link never became ready"
    time.sleep(1.2)  # references, parameters, poses, heartbeats and claims of our own on the bus
    c = link.counters
    assert c.references_tx > 20 and c.poses_tx >= 5 and c.parameters_tx >= 1, c
    assert c.address_conflicts == 0 and c.own_echo == 0, c
    assert not link.faults.address_conflict, link.faults.reasons
    for n, (what, ident) in enumerate(_SPOOFS.items(), start=1):
        rival.send(can.Message(arbitration_id=ident, is_extended_id=True, data=bytes(8)))
        assert wait_until(lambda n=n: link.counters.address_conflicts >= n, 2.0), what
        assert link.faults.address_conflict, what
    assert "PGN 0xFF21" in link.faults.reason_of("address_conflict")  # one conflict: its first frame names it


def test_spoofed_frames_of_every_own_pgn_raise_address_conflict_on_the_virtual_bus():
    channel = f"own-address-{uuid.uuid4().hex}"
    with _service_machine("virtual", channel) as (parts, mc):
        rival = can.Bus(interface="virtual", channel=channel)
        try:
            _moves_without_a_false_conflict_then_sees_each_spoof(parts, mc, rival)
        finally:
            rival.shutdown()


def test_spoofed_frames_of_every_own_pgn_raise_address_conflict_through_the_loopback_hub():
    """The hub filters each client's frames on the hub's side (python-can-remote) and never returns a client's
    own frames to it: the same holds across processes."""
    with LoopbackHub() as hub, _service_machine("remote", hub.url) as (parts, mc):
        rival = open_bus("remote", hub.url)
        try:
            _moves_without_a_false_conflict_then_sees_each_spoof(parts, mc, rival)
        finally:
            rival.shutdown()


def test_the_planner_filters_pass_every_frame_with_our_address_and_otherwise_the_planners_pgns():
    from bridge.service.machine import planner_filters

    channel = f"own-filter-{uuid.uuid4().hex}"
    rx = can.Bus(interface="virtual", channel=channel, can_filters=planner_filters(166))
    tx = can.Bus(interface="virtual", channel=channel)
    try:
        from bridge.isobus.j1939 import decode_id

        for m in load_codec().database.messages:
            pgn = decode_id(m.frame_id).pgn
            for source in (166, 169, 240):
                ident = (m.frame_id & 0x1FFFFF00) | source
                tx.send(can.Message(arbitration_id=ident, is_extended_id=True, data=bytes(8)))
                got = rx.recv(0.2 if source == 166 or pgn in PLANNER_PGNS else 0.02)
                assert (got is not None) == (source == 166 or pgn in PLANNER_PGNS), (m.name, source)
    finally:
        rx.shutdown()
        tx.shutdown()
