"""The machine side's bus filters (``bridge.service.machine.pgn_filters``): a bus receives exactly the
J1939 PGNs it reads, from any source and (PDU1) to any destination — checked by sending frames of
every PGN the DBC knows and a few it does not through a python-can virtual channel."""

from __future__ import annotations

import uuid

import can
import pytest

from bridge.isobus.codec import load_codec
from bridge.isobus.j1939 import decode_id
from bridge.service.machine import PLANNER_PGNS, TWIN_PGNS, pgn_filters


def _frame(pgn: int, source: int, dest: int, priority: int) -> can.Message:
    pdu1 = ((pgn >> 8) & 0xFF) < 0xF0
    ident = (priority << 26) | ((pgn | (dest if pdu1 else 0)) << 8) | source
    return can.Message(arbitration_id=ident, data=bytes(8), is_extended_id=True)


@pytest.mark.parametrize("wanted", [PLANNER_PGNS, TWIN_PGNS], ids=["planner", "twin"])
def test_a_filtered_bus_receives_exactly_its_pgns(wanted):
    channel = f"filters-{uuid.uuid4().hex}"
    rx = can.Bus(interface="virtual", channel=channel, can_filters=pgn_filters(wanted))
    tx = can.Bus(interface="virtual", channel=channel)
    try:
        known = {decode_id(m.frame_id).pgn for m in load_codec().database.messages}
        for pgn in sorted(known | wanted | {0xFF24, 0xEF00, 0xFECA}):
            for source, dest, prio in ((169, 0xFF, 6), (3, 0x80, 3), (226, 0x00, 7)):
                tx.send(_frame(pgn, source, dest, prio))
                got = rx.recv(0.2 if pgn in wanted else 0.02)
                assert (got is not None) == (pgn in wanted), (hex(pgn), source, dest)
                if got is not None:
                    assert (
                        decode_id(got.arbitration_id).pgn == pgn
                        and decode_id(got.arbitration_id).source_address == source
                    )
    finally:
        rx.shutdown()
        tx.shutdown()
