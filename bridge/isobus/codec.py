"""Encode and decode every hitch-planner CAN message with cantools and ``hitch.dbc``.

The DBC file is the single source of truth for bit layout, scaling, units and valid
ranges; this module adds the J1939 validity rules (see :mod:`bridge.isobus.j1939`) and maps
signals to the frozen payload dataclasses of :mod:`bridge.isobus.messages` (re-exported here)
in SI units. Decoding rejects — with a :class:`CodecError` saying why — remote/error/
11-bit frames, unknown PGNs, a wrong DLC, reserved raw values and values outside the
DBC range; a "not available" or "error indicator" raw value becomes ``None`` (never a
number). Encoding rejects out-of-range inputs the same way; ``None`` encodes as "not
available".

Each message is serialised in one place: a ``_MessageCodec`` subclass names the DBC
message, its default source address and priority, its signals (typed descriptors:
scaled value, count, raw integer, command flag, enumeration) and writes and reads the
payload's fields one by one.

The slope-sensor messages are standard SAE J1939-71 parameter groups whose definition (the
J1939 digital annex) is not public; their layouts here follow the public manual Axiomatic
UMAX0608XX-1000 "Tri-Axial J1939 CAN Inclinometer", version 9B, sections 2.5.1.1 (SSI, PGN
61459) and 2.5.1.2 (SSI2, PGN 61481), cross-checked against the public DBC in
rusefi/can-log-tools (SSI) and the ifm JD inclination-sensor manual, section 8.3 (SSI2). Their
DBC units are the definition's (deg, deg/s, ms); the ``_deg``-free payload fields are SI (rad,
rad/s, s), converted here. The ground-distance (0xFF26) and crop-row (0xFF27) messages are
proprietary project layouts (no standard message exists; see ``docs/sensors.md``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import Enum, IntEnum
from functools import cache
from importlib import resources
from numbers import Integral
from typing import Any, Generic, TypeVar, cast

import can
import cantools
from cantools.database.can import Database, Message, Signal

from bridge.isobus.j1939 import (
    CYLINDER_ECU_ADDRESS,
    GLOBAL_ADDRESS,
    JOYSTICK_ADDRESS,
    PLANNER_ADDRESS,
    TRACTOR_ECU_ADDRESS,
    J1939Error,
    LimitStatus,
    MachineDirection,
    RawStatus,
    Switch,
    classify_raw,
    decode_id,
    encode_id,
    largest_valid_raw,
)
from bridge.isobus.messages import (
    ACTUATORS,
    GROUND_SENSOR_ADDRESS,
    MAX_COUNTS,
    OPERATOR_SWITCH_ADDRESS,
    ROW_CAMERA_ADDRESS,
    SLOPE_SENSOR_ADDRESS,
    AddressClaimed,
    BasicJoystick,
    CodecError,
    Decoded,
    EcuParameters,
    FigureOfMerit,
    GroundDistance,
    Heartbeat,
    HitchCommand,
    JoystickAxis,
    MeasuredPose,
    Payload,
    PositionCounts,
    PositionMeasurement,
    PressureMeasurement,
    RearHitchStatus,
    RequestPgn,
    RowGuidance,
    SlopeSensorInformation,
    SlopeSensorInformation2,
    WheelBasedSpeed,
)

__all__ = [
    "ACTUATORS",
    "AddressClaimed",
    "BasicJoystick",
    "Codec",
    "CodecError",
    "Decoded",
    "EcuParameters",
    "FRAME_ID_MASK",
    "FigureOfMerit",
    "GroundDistance",
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
    "RowGuidance",
    "SlopeSensorInformation",
    "SlopeSensorInformation2",
    "WheelBasedSpeed",
    "decode",
    "decode_frame",
    "encode",
    "encode_position_reference",
    "load_codec",
]

FRAME_ID_MASK = 0x03FFFF00
"""Identifier bits that select a DBC message: EDP, DP, PF, PS (not priority, SA)."""

T = TypeVar("T")
E = TypeVar("E", bound=IntEnum)
P = TypeVar("P")


# --- DBC signal helpers -------------------------------------------------------------------


def _raw_limits(sig: Signal) -> tuple[int, int]:
    """Raw range that maps into the DBC signal's [minimum, maximum]."""
    all_ones = (1 << sig.length) - 1
    lo = 0 if sig.minimum is None else math.ceil((sig.minimum - sig.offset) / sig.scale - 1e-9)
    hi = all_ones if sig.maximum is None else math.floor((sig.maximum - sig.offset) / sig.scale + 1e-9)
    return max(lo, 0), min(hi, all_ones)


def _valid_limits(sig: Signal, j1939: bool) -> tuple[int, int]:
    """:func:`_raw_limits`; for a J1939 field (``j1939``) without the reserved / error / not-available raw values
    at its top, which carry no number."""
    lo, hi = _raw_limits(sig)
    return (lo, min(hi, largest_valid_raw(sig.length))) if j1939 else (lo, hi)


def _range_text(sig: Signal, j1939: bool = False) -> str:
    """The values ``sig`` may carry, in its DBC unit; a J1939 field's without its special raw values (an exit
    reason code of 62 was refused as "outside 0..63", the DBC range, where 0..61 are allowed)."""
    lo, hi = _valid_limits(sig, j1939)
    low = sig.minimum if sig.minimum is not None else lo * sig.scale + sig.offset
    high = sig.maximum if sig.maximum is not None and hi == _raw_limits(sig)[1] else hi * sig.scale + sig.offset
    return f"{low:g}..{high:g}{(' ' + sig.unit) if sig.unit else ''}"


def _in_range(where: str, sig: Signal, raw: int) -> int:
    """``raw`` if it lies in the DBC range of ``sig``, else :class:`CodecError`."""
    lo, hi = _raw_limits(sig)
    if not lo <= raw <= hi:
        raise CodecError(f"{where}: raw {raw} outside {lo}..{hi} ({_range_text(sig)})")
    return raw


def _j1939_status(where: str, sig: Signal, raw: int) -> RawStatus:
    """The J1939-71 meaning of ``raw``; a reserved value raises :class:`CodecError`."""
    status = classify_raw(raw, sig.length)
    if status is RawStatus.RESERVED:
        raise CodecError(f"{where}: raw {raw} is in the J1939 reserved range")
    return status


def _encode_number(where: str, sig: Signal, value: object, *, integral: bool, j1939: bool, required: bool) -> int:
    """Raw value of a number (scaled unless ``integral``); ``None`` → "not available" unless required.

    ``j1939``: the J1939 "not available"/"error"/reserved raw values may not carry a number.
    """
    if value is None:
        if required or not j1939:
            raise CodecError(f"{where} is required, got None")
        return (1 << sig.length) - 1
    if integral:
        if isinstance(value, bool) or not isinstance(value, Integral):  # numpy integers too
            raise CodecError(f"{where} must be an integer, got {value!r}")
        raw = int(value)
    else:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise CodecError(f"{where} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise CodecError(f"{where} must be finite, got {value!r}")
        raw = round((value - sig.offset) / sig.scale)
    lo, hi = _raw_limits(sig)
    if not lo <= raw <= hi or (j1939 and classify_raw(raw, sig.length) is not RawStatus.VALID):
        raise CodecError(f"{where} = {value!r} outside {_range_text(sig, j1939)}")
    return raw


@dataclass
class _Notes:
    """DBC signals of one frame that carried "not available" or the "error indicator"."""

    unavailable: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)

    def add(self, signal: str, status: RawStatus) -> None:
        (self.unavailable if status is RawStatus.NOT_AVAILABLE else self.errors).append(signal)


# --- typed signal descriptors -------------------------------------------------------------


@dataclass(frozen=True)
class _Signal(ABC, Generic[T]):
    """Payload field ``field_name`` ↔ DBC signal ``name``; ``T`` is the field's type."""

    field_name: str
    name: str

    @property
    def where(self) -> str:
        """How a decoding error names this signal."""
        return f"{self.name} (field {self.field_name})"

    def check_dbc(self, sig: Signal) -> None:
        """Raise :class:`CodecError` if the DBC signal cannot carry this field."""

    @abstractmethod
    def encode(self, where: str, sig: Signal, value: object) -> int:
        """The raw value of ``value`` (checked at run time: payloads are not type-checked)."""

    @abstractmethod
    def decode(self, sig: Signal, raw: int, notes: _Notes) -> T:
        """The field value of ``raw``."""


@dataclass(frozen=True)
class _Scaled(_Signal[float | None]):
    """A scaled physical value (SI); "not available" and "error indicator" are ``None``."""

    def encode(self, where: str, sig: Signal, value: object) -> int:
        return _encode_number(where, sig, value, integral=False, j1939=True, required=False)

    def decode(self, sig: Signal, raw: int, notes: _Notes) -> float | None:
        status = _j1939_status(self.where, sig, raw)
        if status is not RawStatus.VALID:
            notes.add(sig.name, status)
            return None
        return float(_in_range(self.where, sig, raw) * sig.scale + sig.offset)  # a float: DBC factors may be ints


@dataclass(frozen=True)
class _Converted(_Scaled):
    """A scaled value whose DBC unit is not SI (the slope sensor's deg, deg/s, ms).

    The payload field is in SI: field = DBC value x ``si_per_unit`` (e.g. pi/180 for deg -> rad);
    the conversion happens here, at the codec boundary, and errors give both units.
    """

    si_per_unit: float = 1.0
    si_unit: str = ""

    def encode(self, where: str, sig: Signal, value: object) -> int:
        if value is None or isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return super().encode(where, sig, value)  # the same None / type / finite errors
        try:
            return super().encode(where, sig, value / self.si_per_unit)
        except CodecError:
            lo, hi = _valid_limits(sig, True)
            low, high = ((r * sig.scale + sig.offset) * self.si_per_unit for r in (lo, hi))
            wire = _range_text(sig, True)
            raise CodecError(
                f"{where} = {value!r} outside {low:.6g}..{high:.6g} {self.si_unit} ({wire} on the wire)"
            ) from None

    def decode(self, sig: Signal, raw: int, notes: _Notes) -> float | None:
        value = super().decode(sig, raw, notes)
        return None if value is None else value * self.si_per_unit


_RAD_PER_DEG = math.pi / 180.0
_S_PER_MS = 1e-3


@dataclass(frozen=True)
class _Count(_Signal[int | None]):
    """An integer count; "not available" and "error indicator" are ``None``."""

    def encode(self, where: str, sig: Signal, value: object) -> int:
        return _encode_number(where, sig, value, integral=True, j1939=True, required=False)

    def decode(self, sig: Signal, raw: int, notes: _Notes) -> int | None:
        status = _j1939_status(self.where, sig, raw)
        if status is not RawStatus.VALID:
            notes.add(sig.name, status)
            return None
        return _in_range(self.where, sig, raw)


@dataclass(frozen=True)
class _RequiredCount(_Signal[int]):
    """An integer count that must be present: a frame without it is rejected."""

    def encode(self, where: str, sig: Signal, value: object) -> int:
        return _encode_number(where, sig, value, integral=True, j1939=True, required=True)

    def decode(self, sig: Signal, raw: int, notes: _Notes) -> int:
        status = _j1939_status(self.where, sig, raw)
        if status is not RawStatus.VALID:
            raise CodecError(f"{self.where}: {status.value} (raw {raw}) where a value is required")
        return _in_range(self.where, sig, raw)


@dataclass(frozen=True)
class _Raw(_Signal[int]):
    """An integer passed through within the DBC range (no J1939 special values)."""

    def encode(self, where: str, sig: Signal, value: object) -> int:
        return _encode_number(where, sig, value, integral=True, j1939=False, required=True)

    def decode(self, sig: Signal, raw: int, notes: _Notes) -> int:
        return _in_range(self.where, sig, raw)


@dataclass(frozen=True)
class _Flag(_Signal[bool | None]):
    """A 2-bit command: 0 False, 1 True, 3 ``None`` ("no change"); 2 is reserved."""

    def encode(self, where: str, sig: Signal, value: object) -> int:
        if value is not None and not isinstance(value, bool):
            raise CodecError(f"{where} must be True, False or None, got {value!r}")
        return 3 if value is None else int(value)

    def decode(self, sig: Signal, raw: int, notes: _Notes) -> bool | None:
        if raw == 2:
            raise CodecError(f"{self.where}: raw 2 is reserved (0 off, 1 on, 3 no change)")
        return None if raw == 3 else bool(raw)


@dataclass(frozen=True)
class _Enum(_Signal[E]):
    """An :class:`~enum.IntEnum`; the DBC ``VAL_`` table (if any) lists the allowed raw values."""

    enum: type[E]

    def check_dbc(self, sig: Signal) -> None:
        if sig.choices and not set(sig.choices) <= {int(m) for m in self.enum}:
            raise CodecError(f"DBC choices of {self.name} do not match {self.enum.__name__}")

    def encode(self, where: str, sig: Signal, value: object) -> int:
        try:  # the lookup ``self.enum(value)`` does, for any object
            member = next((m for m in self.enum if m.value == value), None)
        except (ValueError, TypeError):
            member = None
        if member is None:
            raise CodecError(f"{where}: {value!r} is not a {self.enum.__name__}")
        raw = int(member)
        if sig.choices and raw not in sig.choices:
            raise CodecError(f"{where}: {self.enum(raw).name} not allowed, raw {sorted(sig.choices)}")
        return raw

    def decode(self, sig: Signal, raw: int, notes: _Notes) -> E:
        allowed = set(sig.choices) if sig.choices else {int(m) for m in self.enum}
        if raw not in allowed:
            raise CodecError(f"{self.where}: raw {raw} is reserved, allowed {sorted(allowed)}")
        return self.enum(raw)


@dataclass(frozen=True)
class _Group(Generic[T]):
    """A tuple-valued payload field carried by several DBC signals, in order."""

    field_name: str
    members: tuple[_Signal[T], ...]


# --- one frame being written or read ------------------------------------------------------


class _Writer:
    """The raw signal values of one frame being encoded, each checked as it is put."""

    def __init__(self, owner: str, message: Message) -> None:
        self.owner = owner
        self.message = message
        self.raw: dict[str, int] = {}

    def put(self, signal: _Signal[T], value: T) -> None:
        """Encode ``value`` into ``signal``; errors name ``owner.field``."""
        sig = self.message.get_signal_by_name(signal.name)
        self.raw[signal.name] = signal.encode(f"{self.owner}.{signal.field_name}", sig, value)

    def put_all(self, group: _Group[T], values: Iterable[T]) -> None:
        """Encode a tuple-valued field, one entry per signal of ``group``."""
        where = f"{self.owner}.{group.field_name}"
        if not isinstance(values, Iterable):  # payload fields are not type-checked at run time
            raise CodecError(f"{where} must be a sequence")
        items = tuple(values)
        if len(items) != len(group.members):
            raise CodecError(f"{where} needs {len(group.members)} entries")
        for signal, item in zip(group.members, items, strict=True):
            self.put(signal, item)


class _Reader:
    """The decoded signal values of one received frame (decoded and checked on construction)."""

    def __init__(self, message: Message, signals: Iterable[_Signal[Any]], raw: dict[str, int]) -> None:
        self.message = message
        self.notes = _Notes()
        self._values: dict[str, object] = {
            s.name: s.decode(message.get_signal_by_name(s.name), raw[s.name], self.notes) for s in signals
        }

    def get(self, signal: _Signal[T]) -> T:
        """The value of ``signal``; of type ``T`` because ``signal.decode`` produced it."""
        return cast(T, self._values[signal.name])

    def get_all(self, group: _Group[T]) -> tuple[T, ...]:
        """The values of a tuple-valued field."""
        return tuple(self.get(s) for s in group.members)


# --- one class per message ----------------------------------------------------------------


class _MessageCodec(ABC, Generic[P]):
    """How payload type ``P`` maps to one DBC message, both directions in one place.

    ``signals`` lists every signal (or group) in the order frames are decoded and
    checked; ``write`` puts the payload's fields, ``read`` builds the payload.
    """

    payload: type[P]
    message: str
    source: int
    priority: int
    dlcs: tuple[int, ...]
    signals: tuple[_Signal[Any] | _Group[Any], ...]

    def flat_signals(self) -> tuple[_Signal[Any], ...]:
        """Every DBC signal of the message, groups expanded, in decoding order."""
        out: list[_Signal[Any]] = []
        for s in self.signals:
            out.extend(s.members if isinstance(s, _Group) else (s,))
        return tuple(out)

    @abstractmethod
    def write(self, p: P, out: _Writer) -> None:
        """Put every field of ``p``."""

    @abstractmethod
    def read(self, r: _Reader) -> P:
        """Build the payload from the decoded signals (may raise :class:`CodecError`)."""


class _PressureCodec(_MessageCodec[PressureMeasurement]):
    LIFT = _Scaled("lift_pa", "LiftPressure")
    TILT = _Scaled("tilt_pa", "TiltPressure")
    TOP = _Scaled("top_pa", "TopPressure")
    SUPPLY = _Scaled("supply_pa", "SupplyPressure")

    payload = PressureMeasurement
    message = "PressureMeasurement"
    source = CYLINDER_ECU_ADDRESS
    priority = 6
    dlcs = (8,)
    signals = (LIFT, TILT, TOP, SUPPLY)

    def write(self, p: PressureMeasurement, out: _Writer) -> None:
        out.put(self.LIFT, p.lift_pa)
        out.put(self.TILT, p.tilt_pa)
        out.put(self.TOP, p.top_pa)
        out.put(self.SUPPLY, p.supply_pa)

    def read(self, r: _Reader) -> PressureMeasurement:
        return PressureMeasurement(
            lift_pa=r.get(self.LIFT), tilt_pa=r.get(self.TILT), top_pa=r.get(self.TOP), supply_pa=r.get(self.SUPPLY)
        )


class _PositionReferenceCodec(_MessageCodec[PositionCounts]):
    LIFT = _RequiredCount("lift", "LiftReference")
    TILT = _RequiredCount("tilt", "TiltReference")
    TOP = _RequiredCount("top", "TopReference")
    LEFT = _RequiredCount("left", "LeftReference")
    RIGHT = _RequiredCount("right", "RightReference")

    payload = PositionCounts
    message = "PositionReference"
    source = PLANNER_ADDRESS
    priority = 3
    dlcs = (8,)
    signals = (LIFT, TILT, TOP, LEFT, RIGHT)  # ACTUATORS order

    def write(self, p: PositionCounts, out: _Writer) -> None:
        out.put(self.LIFT, p.lift)
        out.put(self.TILT, p.tilt)
        out.put(self.TOP, p.top)
        out.put(self.LEFT, p.left)
        out.put(self.RIGHT, p.right)

    def read(self, r: _Reader) -> PositionCounts:
        return PositionCounts(
            lift=r.get(self.LIFT),
            tilt=r.get(self.TILT),
            top=r.get(self.TOP),
            left=r.get(self.LEFT),
            right=r.get(self.RIGHT),
        )


class _PositionMeasurementCodec(_MessageCodec[PositionMeasurement]):
    TILT = _Count("tilt_counts", "TiltMeasurement")
    TOP = _Count("top_counts", "TopMeasurement")
    RIGHT = _Count("right_counts", "RightMeasurement")
    LEFT = _Count("left_counts", "LeftMeasurement")
    STATE = _Raw("system_state", "SystemState")

    payload = PositionMeasurement
    message = "PositionMeasurement"
    source = CYLINDER_ECU_ADDRESS
    priority = 3
    dlcs = (8,)
    signals = (TILT, TOP, RIGHT, LEFT, STATE)

    def write(self, p: PositionMeasurement, out: _Writer) -> None:
        out.put(self.TILT, p.tilt_counts)
        out.put(self.TOP, p.top_counts)
        out.put(self.RIGHT, p.right_counts)
        out.put(self.LEFT, p.left_counts)
        out.put(self.STATE, p.system_state)

    def read(self, r: _Reader) -> PositionMeasurement:
        return PositionMeasurement(
            tilt_counts=r.get(self.TILT),
            top_counts=r.get(self.TOP),
            right_counts=r.get(self.RIGHT),
            left_counts=r.get(self.LEFT),
            system_state=r.get(self.STATE),
        )


class _EcuParametersCodec(_MessageCodec[EcuParameters]):
    CONTROLLERS = _Flag("controllers_enabled", "ControllersEnable")
    WATCHDOG = _Scaled("watchdog_timeout_s", "WatchdogTimeout")
    MULTIPLIERS = _Group(
        "valve_multipliers", tuple(_Scaled("valve_multipliers", f"{a.capitalize()}ValveMultiplier") for a in ACTUATORS)
    )

    payload = EcuParameters
    message = "EcuParameters"
    source = PLANNER_ADDRESS
    priority = 6
    dlcs = (8,)
    signals = (CONTROLLERS, WATCHDOG, MULTIPLIERS)

    def write(self, p: EcuParameters, out: _Writer) -> None:
        out.put(self.CONTROLLERS, p.controllers_enabled)
        out.put(self.WATCHDOG, p.watchdog_timeout_s)
        out.put_all(self.MULTIPLIERS, p.valve_multipliers)

    def read(self, r: _Reader) -> EcuParameters:
        return EcuParameters(
            controllers_enabled=r.get(self.CONTROLLERS),
            watchdog_timeout_s=r.get(self.WATCHDOG),
            valve_multipliers=r.get_all(self.MULTIPLIERS),
        )


class _MeasuredPoseCodec(_MessageCodec[MeasuredPose]):
    X = _Scaled("x_m", "PoseX")
    Z = _Scaled("z_m", "PoseZ")
    ROLL = _Scaled("roll_rad", "PoseRoll")
    PITCH = _Scaled("pitch_rad", "PosePitch")

    payload = MeasuredPose
    message = "MeasuredPose"
    source = PLANNER_ADDRESS
    priority = 6
    dlcs = (8,)
    signals = (X, Z, ROLL, PITCH)

    def write(self, p: MeasuredPose, out: _Writer) -> None:
        out.put(self.X, p.x_m)
        out.put(self.Z, p.z_m)
        out.put(self.ROLL, p.roll_rad)
        out.put(self.PITCH, p.pitch_rad)

    def read(self, r: _Reader) -> MeasuredPose:
        return MeasuredPose(
            x_m=r.get(self.X), z_m=r.get(self.Z), roll_rad=r.get(self.ROLL), pitch_rad=r.get(self.PITCH)
        )


class _RearHitchStatusCodec(_MessageCodec[RearHitchStatus]):
    POSITION = _Scaled("position", "RearHitchPosition")
    IN_WORK = _Enum("in_work", "RearHitchInWork", Switch)
    LIMIT = _Enum("limit_status", "RearHitchLimitStatus", LimitStatus)
    FORCE = _Scaled("nominal_lower_link_force", "RearNominalLowerLinkForce")
    DRAFT = _Scaled("draft_n", "RearDraft")
    EXIT_REASON = _Count("exit_reason_code", "RearHitchExitReasonCode")

    payload = RearHitchStatus
    message = "RearHitchStatus"
    source = TRACTOR_ECU_ADDRESS
    priority = 3
    dlcs = (8,)
    signals = (POSITION, IN_WORK, LIMIT, FORCE, DRAFT, EXIT_REASON)

    def write(self, p: RearHitchStatus, out: _Writer) -> None:
        out.put(self.POSITION, p.position)
        out.put(self.IN_WORK, p.in_work)
        out.put(self.LIMIT, p.limit_status)
        out.put(self.FORCE, p.nominal_lower_link_force)
        out.put(self.DRAFT, p.draft_n)
        out.put(self.EXIT_REASON, p.exit_reason_code)

    def read(self, r: _Reader) -> RearHitchStatus:
        return RearHitchStatus(
            position=r.get(self.POSITION),
            in_work=r.get(self.IN_WORK),
            limit_status=r.get(self.LIMIT),
            nominal_lower_link_force=r.get(self.FORCE),
            draft_n=r.get(self.DRAFT),
            exit_reason_code=r.get(self.EXIT_REASON),
        )


class _WheelBasedSpeedCodec(_MessageCodec[WheelBasedSpeed]):
    SPEED = _Scaled("speed_m_s", "WheelBasedMachineSpeed")
    DISTANCE = _Scaled("distance_m", "WheelBasedMachineDistance")
    POWER_TIME = _Scaled("max_power_time_s", "MaxTimeOfTractorPower")
    DIRECTION = _Enum("direction", "WheelBasedMachineDirection", MachineDirection)
    KEY = _Enum("key_switch", "KeySwitchState", Switch)
    START_STOP = _Enum("start_stop", "ImplementStartStop", Switch)
    REVERSED = _Enum("direction_reversed", "OperatorDirectionReversed", Switch)

    payload = WheelBasedSpeed
    message = "WheelBasedSpeedDistance"
    source = TRACTOR_ECU_ADDRESS
    priority = 3
    dlcs = (8,)
    signals = (SPEED, DISTANCE, POWER_TIME, DIRECTION, KEY, START_STOP, REVERSED)

    def write(self, p: WheelBasedSpeed, out: _Writer) -> None:
        out.put(self.SPEED, p.speed_m_s)
        out.put(self.DISTANCE, p.distance_m)
        out.put(self.POWER_TIME, p.max_power_time_s)
        out.put(self.DIRECTION, p.direction)
        out.put(self.KEY, p.key_switch)
        out.put(self.START_STOP, p.start_stop)
        out.put(self.REVERSED, p.direction_reversed)

    def read(self, r: _Reader) -> WheelBasedSpeed:
        return WheelBasedSpeed(
            speed_m_s=r.get(self.SPEED),
            distance_m=r.get(self.DISTANCE),
            max_power_time_s=r.get(self.POWER_TIME),
            direction=r.get(self.DIRECTION),
            key_switch=r.get(self.KEY),
            start_stop=r.get(self.START_STOP),
            direction_reversed=r.get(self.REVERSED),
        )


class _HeartbeatCodec(_MessageCodec[Heartbeat]):
    SEQUENCE = _Raw("sequence", "HeartbeatSequenceNumber")

    payload = Heartbeat
    message = "Heartbeat"
    source = PLANNER_ADDRESS
    priority = 3
    dlcs = (1, 8)
    signals = (SEQUENCE,)

    def write(self, p: Heartbeat, out: _Writer) -> None:
        out.put(self.SEQUENCE, p.sequence)

    def read(self, r: _Reader) -> Heartbeat:
        return Heartbeat(sequence=r.get(self.SEQUENCE))


@dataclass(frozen=True)
class _AxisSignals:
    """The five signals of one joystick axis (J1939 Basic Joystick Message 1)."""

    position: _Scaled
    neutral: _Enum[Switch]
    negative: _Enum[Switch]
    positive: _Enum[Switch]
    detent: _Enum[Switch]

    @classmethod
    def of(cls, axis: str, negative: str, positive: str) -> _AxisSignals:
        a = axis.upper()
        return cls(
            _Scaled(f"{axis}_position", f"Jstk1{a}AxisPosition"),
            _Enum(f"{axis}_neutral", f"Jstk1{a}AxisNeutral", Switch),
            _Enum(f"{axis}_negative", f"Jstk1{a}Axis{negative}", Switch),
            _Enum(f"{axis}_positive", f"Jstk1{a}Axis{positive}", Switch),
            _Enum(f"{axis}_detent", f"Jstk1{a}AxisDetent", Switch),
        )

    @property
    def signals(self) -> tuple[_Signal[Any], ...]:
        return (self.position, self.neutral, self.negative, self.positive, self.detent)

    def write(self, ax: JoystickAxis, out: _Writer) -> None:
        out.put(self.position, ax.position)
        out.put(self.neutral, ax.neutral)
        out.put(self.negative, ax.negative)
        out.put(self.positive, ax.positive)
        out.put(self.detent, ax.detent)

    def read(self, r: _Reader) -> JoystickAxis:
        return JoystickAxis(
            position=r.get(self.position),
            neutral=r.get(self.neutral),
            negative=r.get(self.negative),
            positive=r.get(self.positive),
            detent=r.get(self.detent),
        )


class _BasicJoystickCodec(_MessageCodec[BasicJoystick]):
    X = _AxisSignals.of("x", "LeftNeg", "RightPos")
    Y = _AxisSignals.of("y", "BackNeg", "FwdPos")
    BUTTONS = _Group("buttons", tuple(_Enum("buttons", f"Jstk1Button{i}", Switch) for i in range(1, 13)))

    payload = BasicJoystick
    message = "BasicJoystickMessage1"
    source = JOYSTICK_ADDRESS
    priority = 3
    dlcs = (8,)
    signals = (*X.signals, *Y.signals, BUTTONS)

    def write(self, p: BasicJoystick, out: _Writer) -> None:
        self.X.write(p.x, out)
        self.Y.write(p.y, out)
        out.put_all(self.BUTTONS, p.buttons)

    def read(self, r: _Reader) -> BasicJoystick:
        return BasicJoystick(x=self.X.read(r), y=self.Y.read(r), buttons=r.get_all(self.BUTTONS))


class _AddressClaimedCodec(_MessageCodec[AddressClaimed]):
    """The 64-bit NAME split into the DBC's NAME fields (start bit and length from the DBC)."""

    NAME = tuple(
        _Raw(s, s)
        for s in (
            "IdentityNumber",
            "ManufacturerCode",
            "EcuInstance",
            "FunctionInstance",
            "Function",
            "NameReserved",
            "VehicleSystem",
            "VehicleSystemInstance",
            "IndustryGroup",
            "ArbitraryAddressCapable",
        )
    )

    payload = AddressClaimed
    message = "AddressClaimed"
    source = PLANNER_ADDRESS
    priority = 6
    dlcs = (8,)
    signals = NAME

    def write(self, p: AddressClaimed, out: _Writer) -> None:
        for s in self.NAME:
            sig = out.message.get_signal_by_name(s.name)
            out.put(s, (p.name >> sig.start) & ((1 << sig.length) - 1))

    def read(self, r: _Reader) -> AddressClaimed:
        return AddressClaimed(name=sum(r.get(s) << r.message.get_signal_by_name(s.name).start for s in self.NAME))


class _RequestPgnCodec(_MessageCodec[RequestPgn]):
    PGN = _Raw("pgn", "RequestedPGN")

    payload = RequestPgn
    message = "RequestPGN"
    source = PLANNER_ADDRESS
    priority = 6
    dlcs = (3, 8)
    signals = (PGN,)

    def write(self, p: RequestPgn, out: _Writer) -> None:
        out.put(self.PGN, p.pgn)

    def read(self, r: _Reader) -> RequestPgn:
        return RequestPgn(pgn=r.get(self.PGN))


class _SlopeSensorCodec(_MessageCodec[SlopeSensorInformation]):
    """SSI, PGN 61459: layout from Axiomatic UMAX0608XX-1000 v9B section 2.5.1.1 (see ``hitch.dbc``)."""

    PITCH = _Converted("pitch_rad", "SsiPitchAngle", _RAD_PER_DEG, "rad")
    ROLL = _Converted("roll_rad", "SsiRollAngle", _RAD_PER_DEG, "rad")
    RATE = _Converted("pitch_rate_rad_s", "SsiPitchRate", _RAD_PER_DEG, "rad/s")
    PITCH_MERIT = _Enum("pitch_merit", "SsiPitchAngleFigureOfMerit", FigureOfMerit)
    ROLL_MERIT = _Enum("roll_merit", "SsiRollAngleFigureOfMerit", FigureOfMerit)
    RATE_MERIT = _Enum("pitch_rate_merit", "SsiPitchRateFigureOfMerit", FigureOfMerit)
    COMPENSATED = _Enum("compensated", "SsiPitchAndRollCompensated", Switch)
    LATENCY = _Converted("latency_s", "SsiMeasurementLatency", _S_PER_MS, "s")

    payload = SlopeSensorInformation
    message = "SlopeSensorInformation"
    source = SLOPE_SENSOR_ADDRESS
    priority = 3
    dlcs = (8,)
    signals = (PITCH, ROLL, RATE, PITCH_MERIT, ROLL_MERIT, RATE_MERIT, COMPENSATED, LATENCY)

    def write(self, p: SlopeSensorInformation, out: _Writer) -> None:
        out.put(self.PITCH, p.pitch_rad)
        out.put(self.ROLL, p.roll_rad)
        out.put(self.RATE, p.pitch_rate_rad_s)
        out.put(self.PITCH_MERIT, p.pitch_merit)
        out.put(self.ROLL_MERIT, p.roll_merit)
        out.put(self.RATE_MERIT, p.pitch_rate_merit)
        out.put(self.COMPENSATED, p.compensated)
        out.put(self.LATENCY, p.latency_s)

    def read(self, r: _Reader) -> SlopeSensorInformation:
        return SlopeSensorInformation(
            pitch_rad=r.get(self.PITCH),
            roll_rad=r.get(self.ROLL),
            pitch_rate_rad_s=r.get(self.RATE),
            pitch_merit=r.get(self.PITCH_MERIT),
            roll_merit=r.get(self.ROLL_MERIT),
            pitch_rate_merit=r.get(self.RATE_MERIT),
            compensated=r.get(self.COMPENSATED),
            latency_s=r.get(self.LATENCY),
        )


class _SlopeSensor2Codec(_MessageCodec[SlopeSensorInformation2]):
    """SSI2, PGN 61481: Axiomatic UMAX0608XX-1000 v9B section 2.5.1.2, ifm JD manual section 8.3."""

    PITCH = _Converted("pitch_rad", "Ssi2PitchAngle", _RAD_PER_DEG, "rad")
    ROLL = _Converted("roll_rad", "Ssi2RollAngle", _RAD_PER_DEG, "rad")
    PITCH_COMP = _Enum("pitch_compensated", "Ssi2PitchCompensation", Switch)
    PITCH_MERIT = _Enum("pitch_merit", "Ssi2PitchFigureOfMerit", FigureOfMerit)
    ROLL_COMP = _Enum("roll_compensated", "Ssi2RollCompensation", Switch)
    ROLL_MERIT = _Enum("roll_merit", "Ssi2RollFigureOfMerit", FigureOfMerit)
    LATENCY = _Converted("latency_s", "Ssi2MeasurementLatency", _S_PER_MS, "s")

    payload = SlopeSensorInformation2
    message = "SlopeSensorInformation2"
    source = SLOPE_SENSOR_ADDRESS
    priority = 3
    dlcs = (8,)
    signals = (PITCH, ROLL, PITCH_COMP, PITCH_MERIT, ROLL_COMP, ROLL_MERIT, LATENCY)

    def write(self, p: SlopeSensorInformation2, out: _Writer) -> None:
        out.put(self.PITCH, p.pitch_rad)
        out.put(self.ROLL, p.roll_rad)
        out.put(self.PITCH_COMP, p.pitch_compensated)
        out.put(self.PITCH_MERIT, p.pitch_merit)
        out.put(self.ROLL_COMP, p.roll_compensated)
        out.put(self.ROLL_MERIT, p.roll_merit)
        out.put(self.LATENCY, p.latency_s)

    def read(self, r: _Reader) -> SlopeSensorInformation2:
        return SlopeSensorInformation2(
            pitch_rad=r.get(self.PITCH),
            roll_rad=r.get(self.ROLL),
            pitch_compensated=r.get(self.PITCH_COMP),
            pitch_merit=r.get(self.PITCH_MERIT),
            roll_compensated=r.get(self.ROLL_COMP),
            roll_merit=r.get(self.ROLL_MERIT),
            latency_s=r.get(self.LATENCY),
        )


class _GroundDistanceCodec(_MessageCodec[GroundDistance]):
    DISTANCE = _Scaled("distance_m", "GroundDistance")
    MERIT = _Enum("merit", "GroundDistanceFigureOfMerit", FigureOfMerit)

    payload = GroundDistance
    message = "ImplementGroundDistance"
    source = GROUND_SENSOR_ADDRESS
    priority = 6
    dlcs = (8,)
    signals = (DISTANCE, MERIT)

    def write(self, p: GroundDistance, out: _Writer) -> None:
        out.put(self.DISTANCE, p.distance_m)
        out.put(self.MERIT, p.merit)

    def read(self, r: _Reader) -> GroundDistance:
        return GroundDistance(distance_m=r.get(self.DISTANCE), merit=r.get(self.MERIT))


class _RowGuidanceCodec(_MessageCodec[RowGuidance]):
    OFFSET = _Scaled("offset_m", "RowLateralOffset")
    MERIT = _Enum("merit", "RowOffsetFigureOfMerit", FigureOfMerit)

    payload = RowGuidance
    message = "RowGuidanceOffset"
    source = ROW_CAMERA_ADDRESS
    priority = 6
    dlcs = (8,)
    signals = (OFFSET, MERIT)

    def write(self, p: RowGuidance, out: _Writer) -> None:
        out.put(self.OFFSET, p.offset_m)
        out.put(self.MERIT, p.merit)

    def read(self, r: _Reader) -> RowGuidance:
        return RowGuidance(offset_m=r.get(self.OFFSET), merit=r.get(self.MERIT))


class _HitchCommandCodec(_MessageCodec[HitchCommand]):
    REAR = _Scaled("rear_position", "RearHitchPositionCommand")

    payload = HitchCommand
    message = "HitchPtoCommands"
    source = OPERATOR_SWITCH_ADDRESS
    priority = 3
    dlcs = (8,)
    signals = (REAR,)

    def write(self, p: HitchCommand, out: _Writer) -> None:
        out.put(self.REAR, p.rear_position)

    def read(self, r: _Reader) -> HitchCommand:
        return HitchCommand(rear_position=r.get(self.REAR))


_MESSAGES: tuple[_MessageCodec[Any], ...] = (
    _PressureCodec(),
    _PositionReferenceCodec(),
    _PositionMeasurementCodec(),
    _EcuParametersCodec(),
    _MeasuredPoseCodec(),
    _RearHitchStatusCodec(),
    _WheelBasedSpeedCodec(),
    _HeartbeatCodec(),
    _BasicJoystickCodec(),
    _AddressClaimedCodec(),
    _RequestPgnCodec(),
    _SlopeSensorCodec(),
    _SlopeSensor2Codec(),
    _GroundDistanceCodec(),
    _RowGuidanceCodec(),
    _HitchCommandCodec(),
)

#: the names of the payload types the codec decodes (as a replay names its records)
PAYLOAD_NAMES: tuple[str, ...] = tuple(m.payload.__name__ for m in _MESSAGES)


def _load_database(path: str) -> Database:
    db = cantools.database.load_file(path, frame_id_mask=FRAME_ID_MASK)
    if not isinstance(db, Database):
        raise CodecError(f"{path} is not a CAN database")
    return db


def _raw_int(message: Message, name: str, value: object) -> int:
    """A raw (unscaled) signal value as cantools returns it: an integer."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise CodecError(f"{message.name}: raw value of {name} is not an integer, got {value!r}")
    return value


class Codec:
    """Encoder/decoder bound to one loaded DBC database (immutable after construction)."""

    def __init__(self, database: Database) -> None:
        self._db = database
        # Memos of the last frames encoded and decoded (a pure function of their key; at rest the
        # same frames repeat at up to 100 Hz). Only successes are stored; bounded by _MEMO_SIZE.
        self._encoded: dict[tuple[Any, ...], tuple[int, bytes]] = {}
        self._decoded: dict[tuple[int, int, bytes], Decoded] = {}
        self._by_type: dict[type, _MessageCodec[Any]] = {}
        self._by_message: dict[str, _MessageCodec[Any]] = {}
        for spec in _MESSAGES:
            message = database.get_message_by_name(spec.message)
            for s in spec.flat_signals():
                s.check_dbc(message.get_signal_by_name(s.name))
            self._by_type[spec.payload] = spec
            self._by_message[spec.message] = spec

    @classmethod
    def from_file(cls, path: str | None = None) -> Codec:
        """Load ``path`` (default: the packaged ``bridge/isobus/hitch.dbc``)."""
        if path is None:
            with resources.as_file(resources.files("bridge.isobus") / "hitch.dbc") as p:
                return cls(_load_database(str(p)))
        return cls(_load_database(path))

    @property
    def database(self) -> Database:
        """The underlying cantools database."""
        return self._db

    def encode(
        self,
        payload: Payload,
        *,
        source: int | None = None,
        destination: int = GLOBAL_ADDRESS,
        priority: int | None = None,
    ) -> can.Message:
        """Encode ``payload`` into a 29-bit frame (unused bits 1).

        Args:
            payload: one of the payload dataclasses.
            source: source address (default per message: planner 166, cylinder ECU
                169, tractor ECU 240, joystick 5, slope sensor 226, ground-distance
                sensor 227, row camera 228).
            destination: destination address, PDU1 messages only (default global).
            priority: 0..7 (default per message: 3 control, 6 others).
        """
        key = _memo_key(payload, source, destination, priority)
        hit = None if key is None else self._encoded.get(key)
        if hit is not None:
            return can.Message(arbitration_id=hit[0], is_extended_id=True, data=hit[1])
        msg = self._encode(payload, source, destination, priority)
        if key is not None:
            _remember(self._encoded, key, (msg.arbitration_id, bytes(msg.data)))
        return msg

    def _encode(self, payload: Payload, source: int | None, destination: int, priority: int | None) -> can.Message:
        spec = self._by_type.get(type(payload))
        if spec is None:
            raise CodecError(f"no CAN message for {type(payload).__name__}")
        message = self._db.get_message_by_name(spec.message)
        owner = type(payload).__name__
        out = _Writer(owner, message)
        spec.write(payload, out)
        data = message.encode(out.raw, scaling=False, padding=True, strict=False)
        try:
            can_id = encode_id(
                decode_id(message.frame_id).pgn,
                spec.source if source is None else source,
                priority=spec.priority if priority is None else priority,
                destination_address=destination,
            )
        except J1939Error as exc:
            raise CodecError(f"{owner}: {exc}") from None
        return can.Message(arbitration_id=can_id, is_extended_id=True, data=data)

    def decode_frame(self, msg: can.Message) -> Decoded:
        """Decode ``msg`` with its identifier fields and unavailable-signal lists; :class:`CodecError` for anything
        but a ``can.Message`` (bytes or None failed as "has no attribute 'is_extended_id'")."""
        if not isinstance(msg, can.Message):
            raise CodecError(
                f"a can.Message is expected (can.Message(arbitration_id=…, is_extended_id=True, data=…)), "
                f"got {type(msg).__name__}"
            )
        if msg.is_extended_id and not (msg.is_error_frame or msg.is_remote_frame):
            key = (msg.arbitration_id, msg.dlc, bytes(msg.data))
            hit = self._decoded.get(key)
            if hit is None:
                d = self._decode_frame(msg)
                _remember(self._decoded, key, d)
                return d
            return Decoded(hit.ident, hit.payload, hit.unavailable, hit.errors, float(msg.timestamp))
        return self._decode_frame(msg)

    def _decode_frame(self, msg: can.Message) -> Decoded:
        if msg.is_error_frame or msg.is_remote_frame:
            raise CodecError(f"{'error' if msg.is_error_frame else 'remote'} frame carries no data")
        if not msg.is_extended_id:
            raise CodecError(f"11-bit id 0x{msg.arbitration_id:03X}: ISO 11783 uses 29-bit ids")
        try:
            ident = decode_id(msg.arbitration_id)
        except J1939Error as exc:
            raise CodecError(str(exc)) from None
        lookup = ident.can_id | (0xFF00 if ident.is_pdu1 else 0)
        try:
            message = self._db.get_message_by_frame_id(lookup, force_extended_id=True)
        except KeyError:
            raise CodecError(f"unknown PGN 0x{ident.pgn:05X} (id 0x{msg.arbitration_id:08X})") from None
        spec = self._by_message[message.name]
        data = bytes(msg.data)
        if msg.dlc != len(data) or len(data) not in spec.dlcs:
            raise CodecError(
                f"{message.name}: DLC {msg.dlc} with {len(data)} data bytes, "
                f"expected {' or '.join(map(str, spec.dlcs))}"
            )
        data = (data + b"\xff" * message.length)[: message.length]
        decoded = message.decode_simple(data, decode_choices=False, scaling=False)
        raw = {name: _raw_int(message, name, value) for name, value in decoded.items()}
        reader = _Reader(message, spec.flat_signals(), raw)
        try:
            payload = spec.read(reader)
        except CodecError as exc:
            raise CodecError(f"{message.name}: {exc}") from None
        notes = reader.notes
        return Decoded(ident, payload, tuple(notes.unavailable), tuple(notes.errors), float(msg.timestamp))

    def decode(self, msg: can.Message) -> Payload:
        """Decode ``msg`` into its payload dataclass."""
        return self.decode_frame(msg).payload


_MEMO_SIZE = 64
"""Entries each codec memo holds before it starts over (the frames of a hitch at rest are a handful)."""


def _memo_key(payload: object, source: int | None, destination: int, priority: int | None) -> tuple[Any, ...] | None:
    """The encode memo key: the arguments and each payload field, each with its exact type (so 1,
    1.0 and True stay apart), or None (no memo) unless every field is a plain number, string,
    None or enum member."""
    try:
        values = tuple(vars(payload).values())
    except TypeError:
        return None
    for v in values:
        if type(v) not in _MEMO_LEAVES and not isinstance(v, Enum):
            return None
    args = (source, destination, priority)
    return (type(payload), *((type(v), v) for v in args), *((type(v), v) for v in values))


_MEMO_LEAVES = (int, float, str, bool, type(None))


def _remember(memo: dict[Any, Any], key: Any, value: Any) -> None:
    if len(memo) >= _MEMO_SIZE:
        memo.clear()
    memo[key] = value


@cache
def load_codec(path: str | None = None) -> Codec:
    """The codec for ``path`` (default packaged DBC), loaded once and reused."""
    return Codec.from_file(path)


def encode(
    payload: Payload, *, source: int | None = None, destination: int = GLOBAL_ADDRESS, priority: int | None = None
) -> can.Message:
    """Encode with the default codec; see :meth:`Codec.encode`."""
    return load_codec().encode(payload, source=source, destination=destination, priority=priority)


def decode(msg: can.Message) -> Payload:
    """Decode with the default codec; see :meth:`Codec.decode`."""
    return load_codec().decode(msg)


def decode_frame(msg: can.Message) -> Decoded:
    """Decode with the default codec; see :meth:`Codec.decode_frame`."""
    return load_codec().decode_frame(msg)


def encode_position_reference(counts: PositionCounts, source: int = PLANNER_ADDRESS) -> can.Message:
    """Encode the five-cylinder reference (PGN 0xFF21) from ``source``."""
    return load_codec().encode(counts, source=source)
