"""The cylinder ECU's system-state byte, decoded by the planner side (bit layout by hand)."""

import pytest

from bridge.isobus.messages import CodecError
from bridge.isobus.system_state import decode_system_state


def test_state_byte_layout():
    s = decode_system_state(0b0011_0101)
    assert (
        s.controllers_on,
        s.watchdog_tripped,
        s.end_stop_relay,
        s.no_reference_since_restart,
        s.restart_count_mod16,
    ) == (True, False, True, False, 3)
    with pytest.raises(CodecError, match="0…255"):
        decode_system_state(256)
