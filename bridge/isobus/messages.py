"""Frozen payload dataclasses of every hitch-planner CAN message, in SI units.

One dataclass per DBC message (see ``bridge/isobus/hitch.dbc``); :mod:`bridge.isobus.codec` maps them
to and from frames and re-exports every name here. Constructors validate what can be
checked without the DBC (integer ranges, reserved values, tuple lengths) and raise
:class:`CodecError` naming the field and its allowed range; ``None`` means "not
available" (or "no change" for :class:`EcuParameters`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from numbers import Integral
from typing import TypeAlias

from bridge.isobus.j1939 import J1939Id, LimitStatus, MachineDirection, Switch
from planner.errors import HitchInputError

__all__ = [
    "ACTUATORS",
    "AddressClaimed",
    "BasicJoystick",
    "CodecError",
    "Decoded",
    "EcuParameters",
    "FigureOfMerit",
    "GROUND_AHEAD_SENSOR_ADDRESS",
    "GROUND_SENSOR_ADDRESS",
    "GroundDistance",
    "Heartbeat",
    "JoystickAxis",
    "MAX_COUNTS",
    "MeasuredPose",
    "PGN_GROUND_DISTANCE",
    "PGN_ROW_GUIDANCE",
    "PGN_SLOPE_SENSOR_INFORMATION",
    "PGN_SLOPE_SENSOR_INFORMATION_2",
    "Payload",
    "PositionCounts",
    "PositionMeasurement",
    "PressureMeasurement",
    "RearHitchStatus",
    "ROW_CAMERA_ADDRESS",
    "RequestPgn",
    "RowGuidance",
    "SLOPE_SENSOR_ADDRESS",
    "SlopeSensorInformation",
    "SlopeSensorInformation2",
    "WheelBasedSpeed",
    "HitchCommand",
    "PGN_HITCH_PTO_COMMANDS",
    "OPERATOR_SWITCH_ADDRESS",
]

ACTUATORS = ("lift", "tilt", "top", "left", "right")
"""Actuator order used by every tuple-valued field of this module."""
MAX_COUNTS = 1021
"""Largest 10-bit AD value carried as a number (1022 = error, 1023 = not available)."""

PGN_SLOPE_SENSOR_INFORMATION = 61459  # 0xF013
"""SAE J1939-71 Slope Sensor Information (SSI)."""
PGN_SLOPE_SENSOR_INFORMATION_2 = 61481  # 0xF029
"""SAE J1939-71 Slope Sensor Information 2 (SSI2, extended range)."""
PGN_GROUND_DISTANCE = 0xFF26
"""Proprietary: implement ground distance (project layout, no standard message exists)."""
PGN_ROW_GUIDANCE = 0xFF27
"""Proprietary: crop-row lateral offset (project layout, no standard message exists)."""
SLOPE_SENSOR_ADDRESS = 0xE2
"""Source address of the tractor's slope sensor (226, self-configurable range; project choice)."""
GROUND_SENSOR_ADDRESS = 0xE3
"""Source address of the implement's ground-distance sensor (227; project choice)."""
ROW_CAMERA_ADDRESS = 0xE4
"""Source address of the crop-row camera (228; project choice)."""
PGN_HITCH_PTO_COMMANDS = 65090  # 0xFE42
"""ISO 11783-7 Hitch and PTO commands (the operator's rear hitch raise / lower switch here)."""
OPERATOR_SWITCH_ADDRESS = 0xE5
"""Source address of the operator's rear hitch switch (229; project choice)."""
GROUND_AHEAD_SENSOR_ADDRESS = 0xE6
"""Source address of the look-ahead ground-distance sensor on the tractor's front (230; project choice):
the same PGN 0xFF26 as the implement's sensor, told apart by its sender."""


class CodecError(HitchInputError):
    """A frame or payload that must not reach the planner; the message says why."""


def _require_int(owner: str, name: str, value: object, low: int, high: int) -> int:
    """``value`` as an ``int`` if it is an integer (a numpy one too: counts come from numpy arrays, and
    ``np.int64(140)`` was refused) in ``low..high``, else :class:`CodecError`; not a bool."""
    if isinstance(value, bool) or not isinstance(value, Integral) or not low <= int(value) <= high:
        raise CodecError(f"{owner}.{name} must be an integer in {low}..{high}, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class PositionCounts:
    """Five cylinder positions as 10-bit AD counts, 0..1021 (PGN 0xFF21 reference).

    Counts are the boundary unit of the cylinder ECU (thesis table 3-1 / 3-2 map
    them linearly to stroke in m, lift angle in rad).
    """

    lift: int
    tilt: int
    top: int
    left: int
    right: int

    def __post_init__(self) -> None:
        for name in ACTUATORS:  # kept as int: the codec and its memo take Python integers
            object.__setattr__(self, name, _require_int("PositionCounts", name, getattr(self, name), 0, MAX_COUNTS))

    def as_tuple(self) -> tuple[int, int, int, int, int]:
        """The counts in :data:`ACTUATORS` order."""
        return (self.lift, self.tilt, self.top, self.left, self.right)


@dataclass(frozen=True)
class PositionMeasurement:
    """Cylinder ECU AD readings, PGN 0xFF22 (thesis table 5-2); ``None`` = unavailable.

    Lift is not in this message: it comes from the rear hitch status.
    """

    tilt_counts: int | None
    top_counts: int | None
    right_counts: int | None
    left_counts: int | None
    system_state: int = 0
    """Byte 8 bit field; both ends agree on its bits in :mod:`bridge.isobus.system_state` (controllers on,
    watchdog expired, end-stop relay, no reference since restart, restart counter)."""


@dataclass(frozen=True)
class PressureMeasurement:
    """Hydraulic pressures, Pa, PGN 0xFF20 (project layout, 1 kPa resolution)."""

    lift_pa: float | None = None
    tilt_pa: float | None = None
    top_pa: float | None = None
    supply_pa: float | None = None


@dataclass(frozen=True)
class EcuParameters:
    """Cylinder ECU parameters, PGN 0xFF23; ``None`` means "no change".

    Attributes:
        controllers_enabled: unit controllers on/off.
        watchdog_timeout_s: reference watchdog, 0.01..2.5 s (10 ms resolution).
        valve_multipliers: valve command multipliers (thesis table 3-3), 0..1.25
            (0.005 resolution), in :data:`ACTUATORS` order.
    """

    controllers_enabled: bool | None = None
    watchdog_timeout_s: float | None = None
    valve_multipliers: tuple[float | None, ...] = (None,) * len(ACTUATORS)

    def __post_init__(self) -> None:
        if len(self.valve_multipliers) != len(ACTUATORS):
            raise CodecError(
                f"EcuParameters.valve_multipliers needs {len(ACTUATORS)} entries "
                f"{ACTUATORS}, got {len(self.valve_multipliers)}"
            )


@dataclass(frozen=True)
class MeasuredPose:
    """Measured implement pose for logging, PGN 0xFF25: m and rad, 0.1 mm / 0.1 mrad."""

    x_m: float | None = None
    z_m: float | None = None
    roll_rad: float | None = None
    pitch_rad: float | None = None


@dataclass(frozen=True)
class RearHitchStatus:
    """ISO 11783-7 primary/rear hitch status, PGN 65093.

    Attributes:
        position: rear hitch position, fraction of full travel 0..1 (0.4 %/bit).
        in_work: ON = below the in-work threshold.
        limit_status: limit applied to persistent hitch commands.
        nominal_lower_link_force: fraction -1..1 (0.8 %/bit).
        draft_n: draft force, N (10 N/bit).
        exit_reason_code: 0..61 (0 = all clear), ``None`` if unavailable.
    """

    position: float | None = None
    in_work: Switch = Switch.NOT_AVAILABLE
    limit_status: LimitStatus = LimitStatus.NOT_AVAILABLE
    nominal_lower_link_force: float | None = None
    draft_n: float | None = None
    exit_reason_code: int | None = None


@dataclass(frozen=True)
class WheelBasedSpeed:
    """ISO 11783-7 wheel-based speed and distance, PGN 65096 (m/s, m, s)."""

    speed_m_s: float | None = None
    distance_m: float | None = None
    max_power_time_s: float | None = None
    direction: MachineDirection = MachineDirection.NOT_AVAILABLE
    key_switch: Switch = Switch.NOT_AVAILABLE
    start_stop: Switch = Switch.NOT_AVAILABLE
    direction_reversed: Switch = Switch.NOT_AVAILABLE


@dataclass(frozen=True)
class Heartbeat:
    """ISO 11783-7 heartbeat, PGN 61668: sequence 0..250, 251 initial, 254 error,
    255 shutdown; 252-253 are reserved and rejected."""

    sequence: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "sequence", _require_int("Heartbeat", "sequence", self.sequence, 0, 255))
        if self.sequence in (252, 253):
            raise CodecError(f"Heartbeat.sequence {self.sequence} is reserved (252-253)")


@dataclass(frozen=True)
class JoystickAxis:
    """One axis of J1939 Basic Joystick Message 1.

    Attributes:
        position: deflection magnitude from neutral, fraction 0..1 (0.1 %/bit).
        neutral: ON in the neutral position.
        negative: ON when deflected left (X) / back (Y).
        positive: ON when deflected right (X) / forward (Y).
        detent: ON in a detent.
    """

    position: float | None = None
    neutral: Switch = Switch.NOT_AVAILABLE
    negative: Switch = Switch.NOT_AVAILABLE
    positive: Switch = Switch.NOT_AVAILABLE
    detent: Switch = Switch.NOT_AVAILABLE

    def __post_init__(self) -> None:
        if self.negative == Switch.ON and self.positive == Switch.ON:
            raise CodecError("JoystickAxis: negative and positive deflection both ON")

    @property
    def deflection(self) -> float | None:
        """Signed deflection -1..1 for jog, or ``None`` if it cannot be known."""
        if self.position is None:
            return None
        if self.positive == Switch.ON:
            return self.position
        if self.negative == Switch.ON:
            return -self.position
        if self.neutral == Switch.ON or self.position == 0.0:
            return 0.0
        return None


@dataclass(frozen=True)
class BasicJoystick:
    """J1939 Basic Joystick Message 1, PGN 0xFDD6 (thesis joystick, id 0x0CFDD605)."""

    x: JoystickAxis = field(default_factory=JoystickAxis)
    y: JoystickAxis = field(default_factory=JoystickAxis)
    buttons: tuple[Switch, ...] = (Switch.NOT_AVAILABLE,) * 12
    """Buttons 1..12 in order."""

    def __post_init__(self) -> None:
        if len(self.buttons) != 12:
            raise CodecError(f"BasicJoystick.buttons needs 12 entries, got {len(self.buttons)}")

    def pressed(self, button: int) -> bool:
        """True if button 1..12 reports 'pressed'."""
        _require_int("BasicJoystick", "button", button, 1, 12)
        return self.buttons[button - 1] == Switch.ON


@dataclass(frozen=True)
class AddressClaimed:
    """Address Claimed, PGN 60928: the sender's 64-bit NAME (see bridge.isobus.address_claim)."""

    name: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", _require_int("AddressClaimed", "name", self.name, 0, (1 << 64) - 1))


@dataclass(frozen=True)
class RequestPgn:
    """Request, PGN 59904: asks the destination to send ``pgn``."""

    pgn: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "pgn", _require_int("RequestPgn", "pgn", self.pgn, 0, 0x3FFFF))


class FigureOfMerit(IntEnum):
    """J1939 figure of merit of a slope-sensor value (SPN 3323-3325, 4979, 4981), 2 bits."""

    FULLY_FUNCTIONAL = 0
    """Data within the sensor's specification."""
    DEGRADED = 1
    """Data suspect due to environmental conditions."""
    ERROR = 2
    NOT_AVAILABLE = 3


@dataclass(frozen=True)
class SlopeSensorInformation:
    """SAE J1939-71 Slope Sensor Information (SSI), PGN 61459 (0xF013), in rad, rad/s, s.

    Layout (0.002 deg/bit, offset -64 deg, -64..64.51 deg on the wire) in ``hitch.dbc``; public
    source: Axiomatic UMAX0608XX-1000 "Tri-Axial J1939 CAN Inclinometer" v9B, section 2.5.1.1.
    Signs follow SAE J670 (x forward, y right, z down): pitch positive nose up, roll positive
    right side down. ``None`` = not available (or error indicator, see :class:`Decoded`).

    Attributes:
        pitch_rad: pitch angle (SPN 3318), within ±64 deg.
        roll_rad: roll angle (SPN 3319), within ±64 deg.
        pitch_rate_rad_s: pitch rate (SPN 3322), within ±64 deg/s.
        pitch_merit, roll_merit, pitch_rate_merit: figures of merit (SPN 3323-3325).
        compensated: pitch and roll compensated (SPN 3326): ON = compensation on.
        latency_s: roll and pitch measurement latency (SPN 3327), 0..0.125 s, 0.5 ms steps.
    """

    pitch_rad: float | None = None
    roll_rad: float | None = None
    pitch_rate_rad_s: float | None = None
    pitch_merit: FigureOfMerit = FigureOfMerit.NOT_AVAILABLE
    roll_merit: FigureOfMerit = FigureOfMerit.NOT_AVAILABLE
    pitch_rate_merit: FigureOfMerit = FigureOfMerit.NOT_AVAILABLE
    compensated: Switch = Switch.NOT_AVAILABLE
    latency_s: float | None = None


@dataclass(frozen=True)
class SlopeSensorInformation2:
    """SAE J1939-71 Slope Sensor Information 2 (SSI2, extended range), PGN 61481 (0xF029), rad, s.

    1/32768 deg/bit, offset -250 deg (-250..252 deg on the wire); public sources: Axiomatic
    UMAX0608XX-1000 v9B section 2.5.1.2 and the ifm JD inclination sensor manual section 8.3.
    Signs as :class:`SlopeSensorInformation`.
    """

    pitch_rad: float | None = None
    roll_rad: float | None = None
    pitch_compensated: Switch = Switch.NOT_AVAILABLE
    pitch_merit: FigureOfMerit = FigureOfMerit.NOT_AVAILABLE
    roll_compensated: Switch = Switch.NOT_AVAILABLE
    roll_merit: FigureOfMerit = FigureOfMerit.NOT_AVAILABLE
    latency_s: float | None = None


@dataclass(frozen=True)
class GroundDistance:
    """Implement ground distance, proprietary PGN 0xFF26 (project layout): m, 0.1 mm steps, 0..6.4255 m.

    The distance from the implement's ground sensor to the ground below it.
    """

    distance_m: float | None = None
    merit: FigureOfMerit = FigureOfMerit.NOT_AVAILABLE


@dataclass(frozen=True)
class RowGuidance:
    """Crop-row lateral offset, proprietary PGN 0xFF27 (project layout): m, 0.1 mm steps, -3.2..3.2255 m.

    The crop row's lateral position relative to the implement centre, + to the left (hitch frame x).
    """

    offset_m: float | None = None
    merit: FigureOfMerit = FigureOfMerit.NOT_AVAILABLE


@dataclass(frozen=True)
class HitchCommand:
    """ISO 11783-7 Hitch and PTO commands, PGN 65090: the rear hitch position command (SPN 1875), a
    fraction of full travel 0..1 (0.4 %/bit), ``None`` when not available. This project reads it as the
    operator's raise / lower switch (>= 0.9 raise, <= 0.1 lower, else released; ``docs/implements.md``)."""

    rear_position: float | None = None


Payload: TypeAlias = (
    PositionCounts
    | PositionMeasurement
    | PressureMeasurement
    | EcuParameters
    | MeasuredPose
    | RearHitchStatus
    | WheelBasedSpeed
    | Heartbeat
    | BasicJoystick
    | AddressClaimed
    | RequestPgn
    | SlopeSensorInformation
    | SlopeSensorInformation2
    | GroundDistance
    | RowGuidance
    | HitchCommand
)
"""Any payload dataclass the codec maps to a CAN message."""


@dataclass(frozen=True)
class Decoded:
    """A decoded frame: identifier fields, payload and which signals were unavailable.

    ``unavailable`` and ``errors`` name the DBC signals that carried "not available"
    and "error indicator"; the matching payload fields are ``None``.
    """

    ident: J1939Id
    payload: Payload
    unavailable: tuple[str, ...] = ()
    errors: tuple[str, ...] = ()
    timestamp_s: float = 0.0

    @property
    def source_address(self) -> int:
        """Sender's source address."""
        return self.ident.source_address
