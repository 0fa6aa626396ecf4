"""The cylinder ECU's system-state byte (byte 8 of 0xFF22, thesis table 5-2): what both ends of the bus agree on.

System-state byte (byte 8 of 0xFF22, thesis table 5-2; bit meaning defined here):

=====  =================================================================
bit 0  controllers on (the ECU's on/off switch)
bit 1  watchdog expired: valves held at zero (also before the first reference)
bit 2  end-stop relay engaged on at least one cylinder
bit 3  no reference received since the last (re)start
4–7    restart counter modulo 16 (0 at first power-up, +1 per restart)
=====  =================================================================

A planner detects an ECU restart by a change of bits 4–7 or by bit 3 appearing.

**Not available.** 0xFF is the J1939 "not available" byte. A 0xFF22 whose four readings are not available and
whose system-state byte is 0xFF — an all-0xFF frame (bytes 6–7 are 0xFF anyway) — is a frame that has nothing
to report, from an ECU that cannot measure or a node that fills its frame with 0xFF: its system-state byte is no
state (:func:`measurement_not_available`), and the planner reads neither its restart counter (it read "15", and
the next real frame as another restart, in a CAN fuzz trial) nor its bits. With any reading available, 0xFF is a
state like any other (every flag set, restart counter 15).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bridge.isobus.messages import CodecError, PositionMeasurement

__all__ = [
    "STATE_CONTROLLERS_ON",
    "STATE_END_STOP_RELAY",
    "STATE_NOT_AVAILABLE",
    "STATE_NO_REFERENCE",
    "STATE_RESTART_SHIFT",
    "STATE_WATCHDOG_TRIPPED",
    "SystemStatus",
    "decode_system_state",
    "measurement_not_available",
]

STATE_CONTROLLERS_ON = 0x01
STATE_WATCHDOG_TRIPPED = 0x02
STATE_END_STOP_RELAY = 0x04
STATE_NO_REFERENCE = 0x08
STATE_RESTART_SHIFT = 4
#: the J1939 "not available" byte (all ones): no system state in a frame without readings (module docstring)
STATE_NOT_AVAILABLE = 0xFF


@dataclass(frozen=True)
class SystemStatus:
    """Decoded system-state byte (see the module docstring for the bit layout)."""

    controllers_on: bool
    watchdog_tripped: bool
    end_stop_relay: bool
    no_reference_since_restart: bool
    restart_count_mod16: int


def decode_system_state(state: int) -> SystemStatus:
    """Decode the system-state byte 0…255."""
    if isinstance(state, bool) or not isinstance(state, (int, np.integer)) or not 0 <= int(state) <= 255:
        raise CodecError(f"system state must be an integer byte 0…255, got {state!r}")
    s = int(state)
    return SystemStatus(
        controllers_on=bool(s & STATE_CONTROLLERS_ON),
        watchdog_tripped=bool(s & STATE_WATCHDOG_TRIPPED),
        end_stop_relay=bool(s & STATE_END_STOP_RELAY),
        no_reference_since_restart=bool(s & STATE_NO_REFERENCE),
        restart_count_mod16=s >> STATE_RESTART_SHIFT,
    )


def measurement_not_available(m: PositionMeasurement) -> bool:
    """``m`` (a decoded 0xFF22) has nothing to report: no reading available and the system-state byte 0xFF (an
    all-0xFF frame; module docstring). Its system state must not be read (no restart counter, no watchdog bit)."""
    readings = (m.tilt_counts, m.top_counts, m.right_counts, m.left_counts)
    return m.system_state == STATE_NOT_AVAILABLE and all(r is None for r in readings)
