"""ISO 11783 / SAE J1939 on the hitch's CAN bus: what goes on the wire and what it means.

The protocol layer between the planner and the cylinder ECU, with no bus, thread or
clock of its own:

* :mod:`bridge.isobus.j1939` — 29-bit identifiers, addresses, PGNs, raw-value ranges, bus load;
* :mod:`bridge.isobus.messages` — one frozen payload dataclass per CAN message, SI units;
* :mod:`bridge.isobus.codec` — payloads to and from frames through ``hitch.dbc``;
* :mod:`bridge.isobus.address_claim` — NAME and address claiming (ISO 11783-5);
* :mod:`bridge.isobus.heartbeat` — heartbeat sender and monitor (ISO 11783-7);
* :mod:`bridge.isobus.system_state` — the cylinder ECU's system-state byte.

The names below load lazily (PEP 562): ``import bridge.isobus`` imports none of the
modules, and ``import bridge.isobus.j1939`` does not load cantools.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bridge.isobus.address_claim import (
        CLAIM_WAIT_S,
        SELF_CONFIGURABLE_RANGE,
        AddressClaimer,
        AddressClaimError,
        ClaimState,
        Name,
        cylinder_ecu_name,
        planner_name,
    )
    from bridge.isobus.codec import (
        FRAME_ID_MASK,
        Codec,
        decode,
        decode_frame,
        encode,
        encode_position_reference,
        load_codec,
    )
    from bridge.isobus.heartbeat import (
        HEARTBEAT_PERIOD_S,
        HEARTBEAT_TIMEOUT_S,
        INITIAL_SEQUENCE,
        RECOVERY_COUNT,
        SEQUENCE_ERROR,
        SEQUENCE_MODULUS,
        SEQUENCE_SHUTDOWN,
        HeartbeatError,
        HeartbeatMonitor,
        HeartbeatSender,
        HeartbeatState,
        HeartbeatStatus,
    )
    from bridge.isobus.j1939 import (
        BITRATE_BPS,
        CYLINDER_ECU_ADDRESS,
        GLOBAL_ADDRESS,
        JOYSTICK_ADDRESS,
        NULL_ADDRESS,
        PDU2_THRESHOLD,
        PGN_ADDRESS_CLAIMED,
        PGN_BASIC_JOYSTICK_1,
        PGN_HEARTBEAT,
        PGN_MEASURED_POSE,
        PGN_PARAMETERS,
        PGN_POSITION_MEASUREMENT,
        PGN_POSITION_REFERENCE,
        PGN_PRESSURE_MEASUREMENT,
        PGN_REAR_HITCH_STATUS,
        PGN_REQUEST,
        PGN_WHEEL_BASED_SPEED,
        PLANNER_ADDRESS,
        TRACTOR_ECU_ADDRESS,
        J1939Error,
        J1939Id,
        LimitStatus,
        MachineDirection,
        RawStatus,
        Switch,
        bus_load,
        classify_raw,
        decode_id,
        encode_id,
        frame_bits,
    )
    from bridge.isobus.messages import (
        ACTUATORS,
        MAX_COUNTS,
        AddressClaimed,
        BasicJoystick,
        CodecError,
        Decoded,
        EcuParameters,
        Heartbeat,
        JoystickAxis,
        MeasuredPose,
        Payload,
        PositionCounts,
        PositionMeasurement,
        PressureMeasurement,
        RearHitchStatus,
        RequestPgn,
        WheelBasedSpeed,
    )
    from bridge.isobus.system_state import (
        STATE_CONTROLLERS_ON,
        STATE_END_STOP_RELAY,
        STATE_NO_REFERENCE,
        STATE_RESTART_SHIFT,
        STATE_WATCHDOG_TRIPPED,
        SystemStatus,
        decode_system_state,
    )

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(
        (
            "BITRATE_BPS",
            "CYLINDER_ECU_ADDRESS",
            "GLOBAL_ADDRESS",
            "JOYSTICK_ADDRESS",
            "J1939Error",
            "J1939Id",
            "LimitStatus",
            "MachineDirection",
            "NULL_ADDRESS",
            "PDU2_THRESHOLD",
            "PGN_ADDRESS_CLAIMED",
            "PGN_BASIC_JOYSTICK_1",
            "PGN_HEARTBEAT",
            "PGN_MEASURED_POSE",
            "PGN_PARAMETERS",
            "PGN_POSITION_MEASUREMENT",
            "PGN_POSITION_REFERENCE",
            "PGN_PRESSURE_MEASUREMENT",
            "PGN_REAR_HITCH_STATUS",
            "PGN_REQUEST",
            "PGN_WHEEL_BASED_SPEED",
            "PLANNER_ADDRESS",
            "RawStatus",
            "Switch",
            "TRACTOR_ECU_ADDRESS",
            "bus_load",
            "classify_raw",
            "decode_id",
            "encode_id",
            "frame_bits",
        ),
        "bridge.isobus.j1939",
    ),
    **dict.fromkeys(
        (
            "ACTUATORS",
            "AddressClaimed",
            "BasicJoystick",
            "CodecError",
            "Decoded",
            "EcuParameters",
            "Heartbeat",
            "JoystickAxis",
            "MAX_COUNTS",
            "MeasuredPose",
            "Payload",
            "PositionCounts",
            "PositionMeasurement",
            "PressureMeasurement",
            "RearHitchStatus",
            "RequestPgn",
            "WheelBasedSpeed",
        ),
        "bridge.isobus.messages",
    ),
    **dict.fromkeys(
        (
            "Codec",
            "FRAME_ID_MASK",
            "decode",
            "decode_frame",
            "encode",
            "encode_position_reference",
            "load_codec",
        ),
        "bridge.isobus.codec",
    ),
    **dict.fromkeys(
        (
            "AddressClaimError",
            "AddressClaimer",
            "CLAIM_WAIT_S",
            "ClaimState",
            "Name",
            "SELF_CONFIGURABLE_RANGE",
            "cylinder_ecu_name",
            "planner_name",
        ),
        "bridge.isobus.address_claim",
    ),
    **dict.fromkeys(
        (
            "HEARTBEAT_PERIOD_S",
            "HeartbeatError",
            "HEARTBEAT_TIMEOUT_S",
            "HeartbeatMonitor",
            "HeartbeatSender",
            "HeartbeatState",
            "HeartbeatStatus",
            "INITIAL_SEQUENCE",
            "RECOVERY_COUNT",
            "SEQUENCE_ERROR",
            "SEQUENCE_MODULUS",
            "SEQUENCE_SHUTDOWN",
        ),
        "bridge.isobus.heartbeat",
    ),
    **dict.fromkeys(
        (
            "STATE_CONTROLLERS_ON",
            "STATE_END_STOP_RELAY",
            "STATE_NO_REFERENCE",
            "STATE_RESTART_SHIFT",
            "STATE_WATCHDOG_TRIPPED",
            "SystemStatus",
            "decode_system_state",
        ),
        "bridge.isobus.system_state",
    ),
}

__all__ = [
    # identifiers, addresses, PGNs (bridge.isobus.j1939)
    "BITRATE_BPS",
    "CYLINDER_ECU_ADDRESS",
    "GLOBAL_ADDRESS",
    "JOYSTICK_ADDRESS",
    "J1939Error",
    "J1939Id",
    "LimitStatus",
    "MachineDirection",
    "NULL_ADDRESS",
    "PDU2_THRESHOLD",
    "PGN_ADDRESS_CLAIMED",
    "PGN_BASIC_JOYSTICK_1",
    "PGN_HEARTBEAT",
    "PGN_MEASURED_POSE",
    "PGN_PARAMETERS",
    "PGN_POSITION_MEASUREMENT",
    "PGN_POSITION_REFERENCE",
    "PGN_PRESSURE_MEASUREMENT",
    "PGN_REAR_HITCH_STATUS",
    "PGN_REQUEST",
    "PGN_WHEEL_BASED_SPEED",
    "PLANNER_ADDRESS",
    "RawStatus",
    "Switch",
    "TRACTOR_ECU_ADDRESS",
    "bus_load",
    "classify_raw",
    "decode_id",
    "encode_id",
    "frame_bits",
    # payloads (bridge.isobus.messages)
    "ACTUATORS",
    "AddressClaimed",
    "BasicJoystick",
    "CodecError",
    "Decoded",
    "EcuParameters",
    "Heartbeat",
    "JoystickAxis",
    "MAX_COUNTS",
    "MeasuredPose",
    "Payload",
    "PositionCounts",
    "PositionMeasurement",
    "PressureMeasurement",
    "RearHitchStatus",
    "RequestPgn",
    "WheelBasedSpeed",
    # codec (bridge.isobus.codec)
    "Codec",
    "FRAME_ID_MASK",
    "decode",
    "decode_frame",
    "encode",
    "encode_position_reference",
    "load_codec",
    # address claiming (bridge.isobus.address_claim)
    "AddressClaimError",
    "AddressClaimer",
    "CLAIM_WAIT_S",
    "ClaimState",
    "Name",
    "SELF_CONFIGURABLE_RANGE",
    "cylinder_ecu_name",
    "planner_name",
    # heartbeat (bridge.isobus.heartbeat)
    "HEARTBEAT_PERIOD_S",
    "HeartbeatError",
    "HEARTBEAT_TIMEOUT_S",
    "HeartbeatMonitor",
    "HeartbeatSender",
    "HeartbeatState",
    "HeartbeatStatus",
    "INITIAL_SEQUENCE",
    "RECOVERY_COUNT",
    "SEQUENCE_ERROR",
    "SEQUENCE_MODULUS",
    "SEQUENCE_SHUTDOWN",
    # system-state byte (bridge.isobus.system_state)
    "STATE_CONTROLLERS_ON",
    "STATE_END_STOP_RELAY",
    "STATE_NO_REFERENCE",
    "STATE_RESTART_SHIFT",
    "STATE_WATCHDOG_TRIPPED",
    "SystemStatus",
    "decode_system_state",
]


def __getattr__(name: str) -> Any:
    """Import a public name from its defining module on first use (PEP 562)."""
    source = _SOURCES.get(name)
    if source is None:
        raise AttributeError(f"module 'bridge.isobus' has no attribute {name!r}")
    value = getattr(importlib.import_module(source), name)
    globals()[name] = value  # the next lookup does not come here
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
