"""An all-0xFF 0xFF22 (J1939 "not available") has no system state: its byte 0xFF is not restart counter 15."""

import can

from bridge.isobus.codec import PositionMeasurement, decode_frame
from bridge.isobus.system_state import STATE_NOT_AVAILABLE, decode_system_state, measurement_not_available


def test_an_all_ff_frame_is_not_available_and_a_frame_with_readings_is_read():
    frame = can.Message(arbitration_id=0x0CFF22A9, is_extended_id=True, data=b"\xff" * 8)
    m = decode_frame(frame).payload
    assert m == PositionMeasurement(None, None, None, None, 0xFF)  # 10-bit 1023 = not available, byte 8 = 255
    assert STATE_NOT_AVAILABLE == 0xFF and measurement_not_available(m)
    # any reading available: 0xFF is a state (every flag set, restart counter 15)
    assert not measurement_not_available(PositionMeasurement(300, None, None, None, 0xFF))
    assert decode_system_state(0xFF).restart_count_mod16 == 15
    # no reading, another state: the state is read (the ECU cannot measure but runs)
    assert not measurement_not_available(PositionMeasurement(None, None, None, None, 0x19))
