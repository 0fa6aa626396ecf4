"""Encode and decode every hitch-planner CAN message with cantools and ``hitch.dbc``.

The DBC file is the single source of truth for bit layout, scaling, units and valid
ranges; this module adds the J1939 validity rules (see :mod:`bridge.isobus.j1939`) and maps
signals to the frozen payload dataclasses of :mod:`bridge.isobus.messages` (re-exported here)
in SI units. Decoding rejects — with a :class:`CodecError` saying why — remote/error/
11-bit frames, unknown PGNs, a wrong DLC, reserved raw values and values outside the
DBC range; a "not available" or "error indicator" raw value becomes ``None`` (never a
number). Encoding rejects out-of-range inputs the same way; ``None`` encodes as "not
available".
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from functools import cache
from importlib import resources
from typing import Any

import can
import cantools

from bridge.isobus.j1939 import (
    CYLINDER_ECU_ADDRESS,
    GLOBAL_ADDRESS,
    JOYSTICK_ADDRESS,
    PLANNER_ADDRESS,
    TRACTOR_ECU_ADDRESS,
    LimitStatus,
    MachineDirection,
    RawStatus,
    Switch,
    classify_raw,
    decode_id,
    encode_id,
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

__all__ = [
    "ACTUATORS",
    "AddressClaimed",
    "BasicJoystick",
    "Codec",
    "CodecError",
    "Decoded",
    "EcuParameters",
    "FRAME_ID_MASK",
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
    "decode",
    "decode_frame",
    "encode",
    "encode_position_reference",
    "load_codec",
]

FRAME_ID_MASK = 0x03FFFF00
"""Identifier bits that select a DBC message: EDP, DP, PF, PS (not priority, SA)."""


@dataclass(frozen=True)
class _Field:
    """Payload field ``name`` ↔ DBC signal(s); several signals make a tuple.

    kind: "value" (scaled, unavailable → None), "count" (integer, unavailable →
    None), "enum" (IntEnum, DBC VAL_ table = allowed raw values), "flag" (2-bit
    command: 0 False, 1 True, 3 None), "raw" (integer within the DBC range).
    """

    name: str
    signals: tuple[str, ...]
    kind: str = "value"
    enum: type[IntEnum] | None = None
    required: bool = False


def _f(
    name: str, *signals: str, kind: str = "value", enum: type[IntEnum] | None = None, required: bool = False
) -> _Field:
    return _Field(name, signals, kind, enum, required)


def _axis_fields(axis: str, neg: str, pos: str) -> tuple[_Field, ...]:
    sw = dict(kind="enum", enum=Switch)
    a = axis.upper()
    return (
        _f(f"{axis}_position", f"Jstk1{a}AxisPosition"),
        _f(f"{axis}_neutral", f"Jstk1{a}AxisNeutral", **sw),
        _f(f"{axis}_negative", f"Jstk1{a}Axis{neg}", **sw),
        _f(f"{axis}_positive", f"Jstk1{a}Axis{pos}", **sw),
        _f(f"{axis}_detent", f"Jstk1{a}AxisDetent", **sw),
    )


def _joystick_build(v: dict[str, Any], _message: Any) -> BasicJoystick:
    axis = {
        a: JoystickAxis(*(v[f"{a}_{k}"] for k in ("position", "neutral", "negative", "positive", "detent")))
        for a in "xy"
    }
    return BasicJoystick(x=axis["x"], y=axis["y"], buttons=v["buttons"])


def _joystick_split(p: BasicJoystick, _message: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"buttons": p.buttons}
    for a, ax in (("x", p.x), ("y", p.y)):
        out.update(
            {
                f"{a}_position": ax.position,
                f"{a}_neutral": ax.neutral,
                f"{a}_negative": ax.negative,
                f"{a}_positive": ax.positive,
                f"{a}_detent": ax.detent,
            }
        )
    return out


def _name_build(v: dict[str, Any], message: Any) -> AddressClaimed:
    return AddressClaimed(sum(v[s.name] << s.start for s in message.signals))


def _name_split(p: AddressClaimed, message: Any) -> dict[str, Any]:
    return {s.name: (p.name >> s.start) & ((1 << s.length) - 1) for s in message.signals}


@dataclass(frozen=True)
class _Spec:
    """How one payload type maps to one DBC message."""

    payload: type
    message: str
    source: int
    priority: int
    dlcs: tuple[int, ...]
    fields: tuple[_Field, ...]
    build: Callable[[dict[str, Any], Any], Any] | None = None
    split: Callable[[Any, Any], dict[str, Any]] | None = None


_ENUM = dict(kind="enum", enum=Switch)
_NAME_SIGNALS = (
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

_SPECS = (
    _Spec(
        PressureMeasurement,
        "PressureMeasurement",
        CYLINDER_ECU_ADDRESS,
        6,
        (8,),
        (
            _f("lift_pa", "LiftPressure"),
            _f("tilt_pa", "TiltPressure"),
            _f("top_pa", "TopPressure"),
            _f("supply_pa", "SupplyPressure"),
        ),
    ),
    _Spec(
        PositionCounts,
        "PositionReference",
        PLANNER_ADDRESS,
        3,
        (8,),
        tuple(_f(a, f"{a.capitalize()}Reference", kind="count", required=True) for a in ACTUATORS),
    ),
    _Spec(
        PositionMeasurement,
        "PositionMeasurement",
        CYLINDER_ECU_ADDRESS,
        3,
        (8,),
        tuple(_f(f"{a}_counts", f"{a.capitalize()}Measurement", kind="count") for a in ("tilt", "top", "right", "left"))
        + (_f("system_state", "SystemState", kind="raw"),),
    ),
    _Spec(
        EcuParameters,
        "EcuParameters",
        PLANNER_ADDRESS,
        6,
        (8,),
        (
            _f("controllers_enabled", "ControllersEnable", kind="flag"),
            _f("watchdog_timeout_s", "WatchdogTimeout"),
            _f("valve_multipliers", *(f"{a.capitalize()}ValveMultiplier" for a in ACTUATORS)),
        ),
    ),
    _Spec(
        MeasuredPose,
        "MeasuredPose",
        PLANNER_ADDRESS,
        6,
        (8,),
        (_f("x_m", "PoseX"), _f("z_m", "PoseZ"), _f("roll_rad", "PoseRoll"), _f("pitch_rad", "PosePitch")),
    ),
    _Spec(
        RearHitchStatus,
        "RearHitchStatus",
        TRACTOR_ECU_ADDRESS,
        3,
        (8,),
        (
            _f("position", "RearHitchPosition"),
            _f("in_work", "RearHitchInWork", **_ENUM),
            _f("limit_status", "RearHitchLimitStatus", kind="enum", enum=LimitStatus),
            _f("nominal_lower_link_force", "RearNominalLowerLinkForce"),
            _f("draft_n", "RearDraft"),
            _f("exit_reason_code", "RearHitchExitReasonCode", kind="count"),
        ),
    ),
    _Spec(
        WheelBasedSpeed,
        "WheelBasedSpeedDistance",
        TRACTOR_ECU_ADDRESS,
        3,
        (8,),
        (
            _f("speed_m_s", "WheelBasedMachineSpeed"),
            _f("distance_m", "WheelBasedMachineDistance"),
            _f("max_power_time_s", "MaxTimeOfTractorPower"),
            _f("direction", "WheelBasedMachineDirection", kind="enum", enum=MachineDirection),
            _f("key_switch", "KeySwitchState", **_ENUM),
            _f("start_stop", "ImplementStartStop", **_ENUM),
            _f("direction_reversed", "OperatorDirectionReversed", **_ENUM),
        ),
    ),
    _Spec(Heartbeat, "Heartbeat", PLANNER_ADDRESS, 3, (1, 8), (_f("sequence", "HeartbeatSequenceNumber", kind="raw"),)),
    _Spec(
        BasicJoystick,
        "BasicJoystickMessage1",
        JOYSTICK_ADDRESS,
        3,
        (8,),
        _axis_fields("x", "LeftNeg", "RightPos")
        + _axis_fields("y", "BackNeg", "FwdPos")
        + (_f("buttons", *(f"Jstk1Button{i}" for i in range(1, 13)), **_ENUM),),
        _joystick_build,
        _joystick_split,
    ),
    _Spec(
        AddressClaimed,
        "AddressClaimed",
        PLANNER_ADDRESS,
        6,
        (8,),
        tuple(_f(s, s, kind="raw") for s in _NAME_SIGNALS),
        _name_build,
        _name_split,
    ),
    _Spec(RequestPgn, "RequestPGN", PLANNER_ADDRESS, 6, (3, 8), (_f("pgn", "RequestedPGN", kind="raw"),)),
)


def _raw_limits(sig: Any) -> tuple[int, int]:
    """Raw range that maps into the DBC signal's [minimum, maximum]."""
    lo = math.ceil((sig.minimum - sig.offset) / sig.scale - 1e-9)
    hi = math.floor((sig.maximum - sig.offset) / sig.scale + 1e-9)
    return max(lo, 0), min(hi, (1 << sig.length) - 1)


def _range_text(sig: Any) -> str:
    return f"{sig.minimum:g}..{sig.maximum:g}{(' ' + sig.unit) if sig.unit else ''}"


def _decode_signal(f: _Field, sig: Any, raw: int, unavailable: list[str], errors: list[str]) -> Any:
    where = f"{sig.name} (field {f.name})"
    if f.kind == "enum":
        allowed = set(sig.choices) if sig.choices else {int(m) for m in f.enum}
        if raw not in allowed:
            raise CodecError(f"{where}: raw {raw} is reserved, allowed {sorted(allowed)}")
        return f.enum(raw)
    if f.kind == "flag":
        if raw == 2:
            raise CodecError(f"{where}: raw 2 is reserved (0 off, 1 on, 3 no change)")
        return None if raw == 3 else bool(raw)
    lo, hi = _raw_limits(sig)
    if f.kind != "raw":
        status = classify_raw(raw, sig.length)
        if status in (RawStatus.NOT_AVAILABLE, RawStatus.ERROR):
            if f.required:
                raise CodecError(f"{where}: {status.value} (raw {raw}) where a value is required")
            (unavailable if status is RawStatus.NOT_AVAILABLE else errors).append(sig.name)
            return None
        if status is RawStatus.RESERVED:
            raise CodecError(f"{where}: raw {raw} is in the J1939 reserved range")
    if not lo <= raw <= hi:
        raise CodecError(f"{where}: raw {raw} outside {lo}..{hi} ({_range_text(sig)})")
    return raw if f.kind in ("count", "raw") else raw * sig.scale + sig.offset


def _encode_signal(owner: str, f: _Field, sig: Any, value: Any) -> int:
    where = f"{owner}.{f.name}"
    if f.kind == "enum":
        try:
            raw = int(f.enum(value))
        except (ValueError, TypeError):
            raise CodecError(f"{where}: {value!r} is not a {f.enum.__name__}") from None
        if sig.choices and raw not in sig.choices:
            raise CodecError(f"{where}: {f.enum(raw).name} not allowed, raw {sorted(sig.choices)}")
        return raw
    if f.kind == "flag":
        if value is not None and not isinstance(value, bool):
            raise CodecError(f"{where} must be True, False or None, got {value!r}")
        return 3 if value is None else int(value)
    if value is None:
        if f.required or f.kind == "raw":
            raise CodecError(f"{where} is required, got None")
        return (1 << sig.length) - 1
    integral = f.kind in ("count", "raw")
    if isinstance(value, bool) or not isinstance(value, int if integral else (int, float)):
        kind = "an integer" if integral else "a number"
        raise CodecError(f"{where} must be {kind}, got {value!r}")
    if not integral and not math.isfinite(value):
        raise CodecError(f"{where} must be finite, got {value!r}")
    raw = value if integral else round((value - sig.offset) / sig.scale)
    lo, hi = _raw_limits(sig)
    inside = lo <= raw <= hi
    if not inside or (f.kind != "raw" and classify_raw(raw, sig.length) is not RawStatus.VALID):
        raise CodecError(f"{where} = {value!r} outside {_range_text(sig)}")
    return raw


class Codec:
    """Encoder/decoder bound to one loaded DBC database (immutable after construction)."""

    def __init__(self, database: Any) -> None:
        self._db = database
        self._by_type: dict[type, _Spec] = {}
        self._by_message: dict[str, _Spec] = {}
        for spec in _SPECS:
            message = database.get_message_by_name(spec.message)
            for f in spec.fields:
                for name in f.signals:
                    sig = message.get_signal_by_name(name)
                    members = {int(m) for m in f.enum} if f.enum else set()
                    if f.kind == "enum" and sig.choices and not set(sig.choices) <= members:
                        raise ValueError(f"DBC choices of {name} do not match {f.enum.__name__}")
            self._by_type[spec.payload] = spec
            self._by_message[spec.message] = spec

    @classmethod
    def from_file(cls, path: str | None = None) -> Codec:
        """Load ``path`` (default: the packaged ``bridge/isobus/hitch.dbc``)."""
        if path is None:
            with resources.as_file(resources.files("bridge.isobus") / "hitch.dbc") as p:
                return cls(cantools.database.load_file(str(p), frame_id_mask=FRAME_ID_MASK))
        return cls(cantools.database.load_file(path, frame_id_mask=FRAME_ID_MASK))

    @property
    def database(self) -> Any:
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
                169, tractor ECU 240, joystick 5).
            destination: destination address, PDU1 messages only (default global).
            priority: 0..7 (default per message: 3 control, 6 others).
        """
        spec = self._by_type.get(type(payload))
        if spec is None:
            raise CodecError(f"no CAN message for {type(payload).__name__}")
        message = self._db.get_message_by_name(spec.message)
        values = spec.split(payload, message) if spec.split else {f.name: getattr(payload, f.name) for f in spec.fields}
        raw: dict[str, int] = {}
        owner = type(payload).__name__
        for f in spec.fields:
            try:
                items = tuple(values[f.name]) if len(f.signals) > 1 else (values[f.name],)
            except TypeError:
                raise CodecError(f"{owner}.{f.name} must be a sequence") from None
            if len(items) != len(f.signals):
                raise CodecError(f"{owner}.{f.name} needs {len(f.signals)} entries")
            for name, item in zip(f.signals, items):
                raw[name] = _encode_signal(owner, f, message.get_signal_by_name(name), item)
        data = message.encode(raw, scaling=False, padding=True, strict=False)
        try:
            can_id = encode_id(
                decode_id(message.frame_id).pgn,
                spec.source if source is None else source,
                priority=spec.priority if priority is None else priority,
                destination_address=destination,
            )
        except ValueError as exc:
            raise CodecError(f"{owner}: {exc}") from None
        return can.Message(arbitration_id=can_id, is_extended_id=True, data=data)

    def decode_frame(self, msg: can.Message) -> Decoded:
        """Decode ``msg`` with its identifier fields and unavailable-signal lists."""
        if msg.is_error_frame or msg.is_remote_frame:
            raise CodecError(f"{'error' if msg.is_error_frame else 'remote'} frame carries no data")
        if not msg.is_extended_id:
            raise CodecError(f"11-bit id 0x{msg.arbitration_id:03X}: ISO 11783 uses 29-bit ids")
        try:
            ident = decode_id(msg.arbitration_id)
        except ValueError as exc:
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
        raw = message.decode(data, decode_choices=False, scaling=False)
        unavailable: list[str] = []
        errors: list[str] = []
        values: dict[str, Any] = {}
        for f in spec.fields:
            items = tuple(
                _decode_signal(f, message.get_signal_by_name(n), raw[n], unavailable, errors) for n in f.signals
            )
            values[f.name] = items if len(items) > 1 else items[0]
        try:
            payload = spec.build(values, message) if spec.build else spec.payload(**values)
        except CodecError as exc:
            raise CodecError(f"{message.name}: {exc}") from None
        return Decoded(ident, payload, tuple(unavailable), tuple(errors), float(msg.timestamp))

    def decode(self, msg: can.Message) -> Payload:
        """Decode ``msg`` into its payload dataclass."""
        return self.decode_frame(msg).payload


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
