"""SAE J1939 / ISO 11783-3 identifiers, parameter ranges and bus load.

The 29-bit CAN 2.0B identifier of ISO 11783 (thesis table 1-1) is, from the most
significant bit::

    bits 28-26  priority (0 highest .. 7 lowest)
    bit  25     reserved / extended data page (EDP)
    bit  24     data page (DP)
    bits 23-16  PDU format (PF)
    bits 15-8   PDU specific (PS): destination address if PF < 240 (PDU1),
                group extension if PF >= 240 (PDU2)
    bits 7-0    source address (SA)

The parameter group number is ``EDP·2^17 + DP·2^16 + PF·2^8 (+ PS for PDU2)``.

Raw-value conventions follow the SAE J1939-71 "transmitted signal ranges": a
field of whole bytes is not available when its most significant byte is 0xFF,
carries the error indicator when it is 0xFE and is reserved for 0xFB..0xFD; a
field of any other length is not available when all ones and carries the error
indicator when all ones minus one (e.g. 10-bit 1023 / 1022, 2-bit 3 / 2).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum, IntEnum

from planner.errors import HitchInputError

__all__ = [
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
]

BITRATE_BPS = 250_000
"""ISO 11783-2 bit rate, bit/s."""

GLOBAL_ADDRESS = 255
"""Destination address meaning 'all control functions'."""
NULL_ADDRESS = 254
"""Source address of a control function without an address (cannot claim)."""
PLANNER_ADDRESS = 166
"""Thesis planner computer (Toradex Colibri) source address (thesis table 5-1)."""
CYLINDER_ECU_ADDRESS = 169
"""Thesis cylinder ECU (PhyCORE-MPC555) source address (thesis table 5-1)."""
TRACTOR_ECU_ADDRESS = 240
"""ISO 11783 preferred address of the tractor ECU (TECU)."""
JOYSTICK_ADDRESS = 0x05
"""Bosch-Rexroth joystick source address (thesis id 0x0CFDD605)."""

PDU2_THRESHOLD = 240
"""PDU format values at or above this are PDU2 (broadcast, group extension)."""

PGN_PRESSURE_MEASUREMENT = 0xFF20
PGN_POSITION_REFERENCE = 0xFF21
PGN_POSITION_MEASUREMENT = 0xFF22
PGN_PARAMETERS = 0xFF23
PGN_MEASURED_POSE = 0xFF25
PGN_REAR_HITCH_STATUS = 65093  # 0xFE45
PGN_WHEEL_BASED_SPEED = 65096  # 0xFE48
PGN_HEARTBEAT = 61668  # 0xF0E4
PGN_BASIC_JOYSTICK_1 = 0xFDD6
PGN_ADDRESS_CLAIMED = 0xEE00  # 60928
PGN_REQUEST = 0xEA00  # 59904


class J1939Error(HitchInputError):
    """An identifier field, raw value, DLC or bus-load input outside its J1939 range."""


def _check_range(field: str, value: int, low: int, high: int) -> int:
    """Return ``value`` if it is an int in ``[low, high]``, else raise :class:`J1939Error`."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise J1939Error(f"{field} must be an integer in {low}..{high}, got {value!r}")
    if not low <= value <= high:
        raise J1939Error(f"{field} must be in {low}..{high}, got {value}")
    return value


@dataclass(frozen=True)
class J1939Id:
    """The fields of one 29-bit ISO 11783 / J1939 identifier.

    Attributes:
        priority: 0 (highest) .. 7.
        extended_data_page: reserved bit, 0 or 1.
        data_page: 0 or 1.
        pdu_format: PF, 0..255.
        pdu_specific: PS, 0..255 (destination address for PDU1).
        source_address: SA, 0..255.
    """

    priority: int
    extended_data_page: int
    data_page: int
    pdu_format: int
    pdu_specific: int
    source_address: int

    def __post_init__(self) -> None:
        _check_range("priority", self.priority, 0, 7)
        _check_range("extended_data_page", self.extended_data_page, 0, 1)
        _check_range("data_page", self.data_page, 0, 1)
        _check_range("pdu_format", self.pdu_format, 0, 255)
        _check_range("pdu_specific", self.pdu_specific, 0, 255)
        _check_range("source_address", self.source_address, 0, 255)

    @property
    def is_pdu1(self) -> bool:
        """True for destination-specific PDU1 (PF < 240)."""
        return self.pdu_format < PDU2_THRESHOLD

    @property
    def pgn(self) -> int:
        """Parameter group number (18 bits); PS counts only for PDU2."""
        group_extension = 0 if self.is_pdu1 else self.pdu_specific
        return (self.extended_data_page << 17) | (self.data_page << 16) | (self.pdu_format << 8) | group_extension

    @property
    def destination_address(self) -> int:
        """Destination address: PS for PDU1, the global address for PDU2."""
        return self.pdu_specific if self.is_pdu1 else GLOBAL_ADDRESS

    @property
    def can_id(self) -> int:
        """The 29-bit arbitration identifier."""
        return (
            (self.priority << 26)
            | (self.extended_data_page << 25)
            | (self.data_page << 24)
            | (self.pdu_format << 16)
            | (self.pdu_specific << 8)
            | self.source_address
        )


def encode_id(
    pgn: int,
    source_address: int,
    *,
    priority: int = 6,
    destination_address: int = GLOBAL_ADDRESS,
) -> int:
    """Build a 29-bit identifier from a PGN.

    Args:
        pgn: Parameter group number, 0..0x3FFFF. A PDU1 PGN (PF < 240) must have a
            zero low byte; its destination goes into PS.
        source_address: 0..255.
        priority: 0..7 (J1939 default 6, control messages 3).
        destination_address: 0..255 for PDU1; must be 255 (global) for PDU2.

    Returns:
        The identifier as an int (< 2^29).

    Raises:
        J1939Error: naming the offending field and its allowed range.
    """
    _check_range("pgn", pgn, 0, 0x3FFFF)
    _check_range("destination_address", destination_address, 0, 255)
    pdu_format = (pgn >> 8) & 0xFF
    if pdu_format < PDU2_THRESHOLD:
        if pgn & 0xFF:
            raise J1939Error(f"pgn 0x{pgn:05X} is PDU1 (PF {pdu_format} < 240), its low byte must be 0")
        pdu_specific = destination_address
    else:
        if destination_address != GLOBAL_ADDRESS:
            raise J1939Error(
                f"pgn 0x{pgn:05X} is PDU2 (broadcast): destination_address must be "
                f"{GLOBAL_ADDRESS}, got {destination_address}"
            )
        pdu_specific = pgn & 0xFF
    return J1939Id(
        priority=priority,
        extended_data_page=(pgn >> 17) & 1,
        data_page=(pgn >> 16) & 1,
        pdu_format=pdu_format,
        pdu_specific=pdu_specific,
        source_address=source_address,
    ).can_id


def decode_id(can_id: int) -> J1939Id:
    """Split a 29-bit identifier into its J1939 fields.

    Raises:
        J1939Error: if ``can_id`` is not in 0..0x1FFFFFFF.
    """
    if type(can_id) is int:  # a plain int (not a bool): a pure function of it, memoised
        hit = _DECODED_IDS.get(can_id)
        if hit is not None:
            return hit
    _check_range("can_id", can_id, 0, 0x1FFFFFFF)
    ident = J1939Id(
        priority=(can_id >> 26) & 0x7,
        extended_data_page=(can_id >> 25) & 1,
        data_page=(can_id >> 24) & 1,
        pdu_format=(can_id >> 16) & 0xFF,
        pdu_specific=(can_id >> 8) & 0xFF,
        source_address=can_id & 0xFF,
    )
    if type(can_id) is int:
        if len(_DECODED_IDS) >= _DECODED_IDS_SIZE:
            _DECODED_IDS.clear()
        _DECODED_IDS[can_id] = ident
    return ident


_DECODED_IDS: dict[int, J1939Id] = {}
"""The identifiers decoded lately (a bus carries a handful; frozen values, shared safely)."""
_DECODED_IDS_SIZE = 256


class RawStatus(Enum):
    """Meaning of a raw field value under the J1939-71 transmitted signal ranges."""

    VALID = "valid"
    RESERVED = "reserved"
    ERROR = "error indicator"
    NOT_AVAILABLE = "not available"


def classify_raw(raw: int, length: int) -> RawStatus:
    """Classify the raw value of an unsigned J1939 field of ``length`` bits.

    Whole-byte fields use the most significant byte (0xFF not available, 0xFE
    error, 0xFB..0xFD reserved / parameter specific); other lengths use all ones
    (not available) and all ones minus one (error). One-bit fields are always valid.
    """
    _check_range("length", length, 1, 64)
    _check_range("raw", raw, 0, (1 << length) - 1)
    if length == 1:
        return RawStatus.VALID
    if length % 8 == 0:
        top = raw >> (length - 8)
        if top == 0xFF:
            return RawStatus.NOT_AVAILABLE
        if top == 0xFE:
            return RawStatus.ERROR
        if top >= 0xFB:
            return RawStatus.RESERVED
        return RawStatus.VALID
    all_ones = (1 << length) - 1
    if raw == all_ones:
        return RawStatus.NOT_AVAILABLE
    if raw == all_ones - 1:
        return RawStatus.ERROR
    return RawStatus.VALID


def largest_valid_raw(length: int) -> int:
    """The largest raw value :func:`classify_raw` calls valid for an unsigned field of ``length`` bits (the values
    above it are J1939's reserved, error and not-available ones)."""
    _check_range("length", length, 1, 64)
    if length == 1:
        return 1
    if length % 8 == 0:
        return (0xFB << (length - 8)) - 1
    return (1 << length) - 3


class Switch(IntEnum):
    """A measured two-bit J1939 state (00 off, 01 on, 10 error, 11 not available)."""

    OFF = 0
    ON = 1
    ERROR = 2
    NOT_AVAILABLE = 3


class LimitStatus(IntEnum):
    """ISO 11783-7 hitch position limit status (SPN 5151), 3 bits; 4-5 reserved."""

    NOT_LIMITED = 0
    OPERATOR_LIMITED = 1
    LIMITED_HIGH = 2
    LIMITED_LOW = 3
    NON_RECOVERABLE_FAULT = 6
    NOT_AVAILABLE = 7


class MachineDirection(IntEnum):
    """ISO 11783-7 wheel-based machine direction, 2 bits."""

    REVERSE = 0
    FORWARD = 1
    ERROR = 2
    NOT_AVAILABLE = 3


def frame_bits(dlc: int, *, extended: bool = True, worst_case_stuffing: bool = True) -> int:
    """Bits one data frame occupies on the bus, including the 3-bit interframe space.

    A CAN 2.0B extended data frame has 64 overhead bits (SOF, 29-bit id, SRR, IDE,
    RTR, r1, r0, DLC, 15-bit CRC, CRC delimiter, ACK slot and delimiter, 7-bit EOF)
    plus 8 bits per data byte; a standard frame has 44. Of these, the ``g`` bits from
    SOF to the end of the CRC (54 extended, 34 standard, plus the data) are subject
    to bit stuffing, worst case one stuff bit per 4 bits after the first:
    ``floor((g + 8·dlc − 1) / 4)`` (Davis et al., Real-Time Systems 35, 2007).
    Worst case extended, DLC 8: 64 + 64 + 3 + 29 = 160 bits.
    """
    _check_range("dlc", dlc, 0, 8)
    overhead, stuffable = (64, 54) if extended else (44, 34)
    bits = overhead + 8 * dlc + 3
    if worst_case_stuffing:
        bits += (stuffable + 8 * dlc - 1) // 4
    return bits


def bus_load(
    frames_per_second_by_dlc: Mapping[int, float],
    *,
    bitrate_bps: float = BITRATE_BPS,
    extended: bool = True,
    worst_case_stuffing: bool = True,
) -> float:
    """Fraction of the bus capacity used by periodic traffic.

    Args:
        frames_per_second_by_dlc: frames per second, keyed by data length code 0..8.
        bitrate_bps: bus bit rate, bit/s (ISO 11783: 250 000).
        extended: 29-bit identifiers (True for ISO 11783).
        worst_case_stuffing: count the worst-case number of stuff bits.

    Returns:
        Load as a fraction of ``bitrate_bps`` (1.0 = saturated).

    Raises:
        J1939Error: for a DLC outside 0..8, a negative or non-finite rate or a
            non-positive bit rate.
    """
    if not bitrate_bps > 0 or bitrate_bps == float("inf"):
        raise J1939Error(f"bitrate_bps must be a positive finite number, got {bitrate_bps!r}")
    total_bits_per_s = 0.0
    for dlc, rate in frames_per_second_by_dlc.items():
        if not (rate >= 0 and rate != float("inf")):
            raise J1939Error(f"frames per second for dlc {dlc} must be finite and >= 0, got {rate!r}")
        bits = frame_bits(dlc, extended=extended, worst_case_stuffing=worst_case_stuffing)
        total_bits_per_s += rate * bits
    return total_bits_per_s / bitrate_bps
