"""Codec: bit-exact layouts against hand-packed frames, round trips, rejection of bad frames."""

import math
import random

import can
import pytest

from bridge.isobus.codec import (
    ACTUATORS,
    AddressClaimed,
    BasicJoystick,
    CodecError,
    EcuParameters,
    Heartbeat,
    JoystickAxis,
    MeasuredPose,
    PositionCounts,
    PositionMeasurement,
    PressureMeasurement,
    RearHitchStatus,
    RequestPgn,
    WheelBasedSpeed,
    decode,
    decode_frame,
    encode,
    encode_position_reference,
    load_codec,
)
from bridge.isobus.j1939 import LimitStatus, MachineDirection, Switch


def frame(can_id: int, data: bytes, **kwargs) -> can.Message:
    return can.Message(arbitration_id=can_id, is_extended_id=True, data=data, **kwargs)


def pack_msb_first(values_and_widths, total_bytes=8) -> bytes:
    """Independent packer: concatenate fields MSB first, fill the rest with ones."""
    acc, used = 0, 0
    for value, width in values_and_widths:
        acc, used = (acc << width) | value, used + width
    spare = 8 * total_bytes - used
    return ((acc << spare) | ((1 << spare) - 1)).to_bytes(total_bytes, "big")


# --- 0xFF22 position measurement, bit-exact to thesis table 5-2 -----------------------------

# Thesis table 3-1 calibration ends: tilt 917, top 255, right 503, left 30; state 0x05.
# tilt  917 = 11 1001 0101, top 255 = 00 1111 1111, right 503 = 01 1111 0111, left 30 = 00 0001 1110
HAND_FF22 = bytes(
    [
        0b11100101,  # byte 1: tilt bits 9..2
        0b01001111,  # byte 2: tilt bits 1..0 | top bits 9..4
        0b11110111,  # byte 3: top bits 3..0 | right bits 9..6
        0b11011100,  # byte 4: right bits 5..0 | left bits 9..8
        0b00011110,  # byte 5: left bits 7..0
        0xFF,
        0xFF,  # bytes 6-7 unused
        0x05,  # byte 8 system state
    ]
)


def test_hand_packed_ff22_decodes_to_the_thesis_readings():
    m = decode(frame(0x0CFF22A9, HAND_FF22))
    assert m == PositionMeasurement(
        tilt_counts=917, top_counts=255, right_counts=503, left_counts=30, system_state=0x05
    )


def test_ff22_encodes_exactly_the_hand_packed_bytes_from_the_cylinder_ecu():
    msg = encode(PositionMeasurement(917, 255, 503, 30, 0x05))
    assert bytes(msg.data) == HAND_FF22
    assert msg.arbitration_id == 0x0CFF22A9  # priority 3, PGN 0xFF22, source 169
    assert msg.is_extended_id and msg.dlc == 8


def test_ff22_layout_matches_independent_packing_on_random_values():
    rnd = random.Random(522)
    for _ in range(300):
        tilt, top, right, left = (rnd.randrange(1022) for _ in range(4))
        state = rnd.randrange(256)
        expected = pack_msb_first([(tilt, 10), (top, 10), (right, 10), (left, 10)], 5) + b"\xff\xff" + bytes([state])
        assert bytes(encode(PositionMeasurement(tilt, top, right, left, state)).data) == expected


# --- 0xFF21 position reference (project layout, MSB first like 0xFF22) ------------------------


def test_position_reference_layout_hand_packed():
    counts = PositionCounts(lift=100, tilt=819, top=0, left=5, right=1021)
    # order on the bus: tilt, top, lift, right, left; 50 bits then 14 one-bits
    # tilt 11 0011 0011 | top 00 0000 0000 | lift 00 0110 0100
    # right 11 1111 1101 | left 00 0000 0101
    hand = bytes([0b11001100, 0b11000000, 0b00000001, 0b10010011, 0b11111101, 0b00000001, 0b01111111, 0xFF])
    msg = encode_position_reference(counts)
    assert bytes(msg.data) == hand
    assert msg.arbitration_id == 0x0CFF21A6  # priority 3, PGN 0xFF21, source 166
    assert decode(msg) == counts


def test_position_reference_random_round_trip_and_independent_packing():
    rnd = random.Random(21)
    for _ in range(300):
        c = PositionCounts(*(rnd.randrange(1022) for _ in ACTUATORS))
        msg = encode_position_reference(c, source=0x80)
        expected = pack_msb_first([(c.tilt, 10), (c.top, 10), (c.lift, 10), (c.right, 10), (c.left, 10)])
        assert bytes(msg.data) == expected
        assert msg.arbitration_id & 0xFF == 0x80
        assert decode(msg) == c


@pytest.mark.parametrize("bad", [1022, 1023, -1, 2000, 3.0, True, None])
def test_position_reference_never_carries_a_value_outside_0_1021(bad):
    with pytest.raises(CodecError, match=r"PositionCounts\.tilt must be an integer in 0\.\.1021"):
        PositionCounts(lift=0, tilt=bad, top=0, left=0, right=0)


def test_reference_frame_with_unavailable_value_is_rejected():
    data = pack_msb_first([(500, 10), (500, 10), (1023, 10), (500, 10), (500, 10)])
    with pytest.raises(CodecError, match="LiftReference.*not available.*required"):
        decode(frame(0x0CFF21A6, data))


# --- unavailable values are not numbers --------------------------------------------------------


def test_ff22_not_available_and_error_readings_become_none():
    data = pack_msb_first([(400, 10), (1022, 10), (300, 10), (1023, 10)], 5) + b"\xff\xff\x00"
    d = decode_frame(frame(0x0CFF22A9, data))
    assert d.payload == PositionMeasurement(400, None, 300, None, 0)
    assert d.unavailable == ("LeftMeasurement",)
    assert d.errors == ("TopMeasurement",)
    assert d.source_address == 169


# --- ISO 11783-7 and J1939 messages, hand-packed ---------------------------------------------


def test_rear_hitch_status_hand_packed():
    hand = bytes(
        [
            125,  # position 50 % / 0.4 %
            0b01000111,  # in-work 01 (bits 8,7), limit 000 (bits 6-4), reserved 111
            125,  # nominal lower link force 0 %: (0 + 100) / 0.8
            0x64,
            0x7D,  # draft 1000 N: (1000 + 320000) / 10 = 32100 = 0x7D64, little-endian
            0b11000000,  # exit/reason code 0, bits 8,7 reserved
            0xFF,
            0xFF,
        ]
    )
    expected = RearHitchStatus(
        position=0.5,
        in_work=Switch.ON,
        limit_status=LimitStatus.NOT_LIMITED,
        nominal_lower_link_force=0.0,
        draft_n=1000.0,
        exit_reason_code=0,
    )
    got = decode(frame(0x0CFE45F0, hand))
    assert got.position == pytest.approx(0.5) and got.draft_n == pytest.approx(1000.0)
    assert got.nominal_lower_link_force == pytest.approx(0.0, abs=1e-12)
    assert (got.in_work, got.limit_status, got.exit_reason_code) == (Switch.ON, LimitStatus.NOT_LIMITED, 0)
    assert bytes(encode(expected).data) == hand


def test_rear_hitch_status_position_not_available_and_reserved_values():
    base = bytearray(b"\x64\xff\xff\xff\xff\xff\xff\xff")
    base[0] = 255
    d = decode_frame(frame(0x0CFE45F0, bytes(base)))
    assert d.payload.position is None and "RearHitchPosition" in d.unavailable
    base[0] = 251  # 100.4 %: reserved range
    with pytest.raises(CodecError, match="RearHitchPosition.*reserved"):
        decode(frame(0x0CFE45F0, bytes(base)))
    base[0] = 100
    base[1] = 0b11100111  # limit status 100 = reserved
    with pytest.raises(CodecError, match="RearHitchLimitStatus.*raw 4 is reserved"):
        decode(frame(0x0CFE45F0, bytes(base)))


def test_wheel_based_speed_hand_packed():
    hand = bytes(
        [
            0xC4,
            0x09,  # 2.5 m/s = 2500 mm/s
            0x40,
            0xE2,
            0x01,
            0x00,  # 123.456 m = 123456 mm
            5,  # 5 min of tractor power left
            0b00110101,
        ]
    )  # reversed 00, start/stop 11, key 01, forward 01
    w = WheelBasedSpeed(2.5, 123.456, 300.0, MachineDirection.FORWARD, Switch.ON, Switch.NOT_AVAILABLE, Switch.OFF)
    assert bytes(encode(w).data) == hand
    assert encode(w).arbitration_id == 0x0CFE48F0
    got = decode(frame(0x0CFE48F0, hand))
    assert got.speed_m_s == pytest.approx(2.5) and got.distance_m == pytest.approx(123.456)
    assert got.max_power_time_s == pytest.approx(300.0)
    assert (got.direction, got.key_switch, got.start_stop, got.direction_reversed) == (
        MachineDirection.FORWARD,
        Switch.ON,
        Switch.NOT_AVAILABLE,
        Switch.OFF,
    )


def test_thesis_joystick_frame_decodes_for_jog():
    hand = bytes(
        [
            0b00010000,  # X: position LSBs 00, right 01, left 00, neutral 00
            0b01111101,  # X position bits 9..2: 500 = 0b01 1111 0100 -> 0x7D
            0b00000001,  # Y: neutral 01
            0x00,  # Y position 0
            0b00001111,  # X detent 00, Y detent 00, reserved 1111
            0b01000000,  # button 1 pressed (bits 8,7), buttons 2-4 released
            0x00,  # buttons 5-8 released
            0xFF,  # buttons 9-12 not available
        ]
    )
    j = decode(frame(0x0CFDD605, hand))
    assert j.x.deflection == pytest.approx(0.5)
    assert j.y.deflection == 0.0
    assert j.pressed(1) and not j.pressed(2)
    assert j.buttons[8:] == (Switch.NOT_AVAILABLE,) * 4
    assert bytes(encode(j).data) == hand
    assert encode(j).arbitration_id == 0x0CFDD605


def test_joystick_axis_signs_and_unknowns():
    assert JoystickAxis(0.25, negative=Switch.ON, positive=Switch.OFF).deflection == -0.25
    assert JoystickAxis(0.25, neutral=Switch.OFF).deflection is None  # direction unknown
    assert JoystickAxis(None, positive=Switch.ON).deflection is None


@pytest.mark.parametrize(
    ("x_pos", "match"),
    [(1010, r"Jstk1XAxisPosition.*raw 1010 outside 0\.\.1000"), (None, None)],
)
def test_joystick_position_range(x_pos, match):
    low, high = (x_pos or 0) & 0b11, (x_pos or 0) >> 2
    data = bytes([(low << 6) | 0b010000, high, 0x01, 0x00, 0x0F, 0, 0, 0xFF])
    if match:
        with pytest.raises(CodecError, match=match):
            decode(frame(0x0CFDD605, data))
    else:
        assert decode(frame(0x0CFDD605, data)).x.position == 0.0


def test_joystick_position_error_and_not_available_are_none():
    for raw, bucket in ((1022, "errors"), (1023, "unavailable")):
        data = bytes([((raw & 3) << 6) | 0b010000, raw >> 2, 0x01, 0x00, 0x0F, 0, 0, 0xFF])
        d = decode_frame(frame(0x0CFDD605, data))
        assert d.payload.x.position is None and d.payload.x.deflection is None
        assert getattr(d, bucket) == ("Jstk1XAxisPosition",)


def test_joystick_with_both_directions_on_is_rejected():
    data = bytes([0b00010100, 0x7D, 0x01, 0x00, 0x0F, 0, 0, 0xFF])
    with pytest.raises(CodecError, match="negative and positive deflection both ON"):
        decode(frame(0x0CFDD605, data))


def test_heartbeat_frame_padding_dlc_and_reserved_values():
    msg = encode(Heartbeat(251))
    assert msg.arbitration_id == 0x0CF0E4A6 and bytes(msg.data) == b"\xfb" + b"\xff" * 7
    assert decode(frame(0x0CF0E4A9, b"\x07")) == Heartbeat(7)  # DLC 1 as ISO 11783-7 defines
    with pytest.raises(CodecError, match="reserved"):
        decode(frame(0x0CF0E4A9, b"\xfc" + b"\xff" * 7))
    with pytest.raises(CodecError, match=r"DLC 4 .* expected 1 or 8"):
        decode(frame(0x0CF0E4A9, b"\x07\xff\xff\xff"))


def test_address_claimed_data_is_the_little_endian_name_and_pdu1_lookup_works():
    name = 0xA00C_8200_0123_4567
    msg = encode(AddressClaimed(name), source=254)
    assert msg.arbitration_id == 0x18EEFFFE
    assert bytes(msg.data) == name.to_bytes(8, "little")
    assert decode(msg) == AddressClaimed(name)
    req = encode(RequestPgn(0xEE00), source=166, destination=169)
    assert req.arbitration_id == 0x18EAA9A6 and bytes(req.data) == b"\x00\xee\x00"
    d = decode_frame(req)
    assert d.payload == RequestPgn(0xEE00) and d.ident.destination_address == 169


def test_parameters_hand_packed_thesis_multipliers():
    p = EcuParameters(
        controllers_enabled=True, watchdog_timeout_s=0.1, valve_multipliers=(1.0, 0.5, 0.5, 0.2, 0.2)
    )  # lift, tilt, top, left, right
    # byte1 0b111111_01, watchdog 10 x 10 ms, then tilt 100, top 100, lift 200, right 40, left 40
    assert bytes(encode(p).data) == bytes([0xFD, 10, 100, 100, 200, 40, 40, 0xFF])
    assert decode(encode(p)) == p
    unchanged = decode(frame(0x18FF23A6, b"\xff" * 8))
    assert unchanged == EcuParameters()  # everything "no change"


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (bytes([0xFE, 10, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]), "ControllersEnable.*reserved"),
        (bytes([0xFD, 0, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]), r"WatchdogTimeout.*outside 1\.\.250"),
        (bytes([0xFD, 10, 251, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]), "TiltValveMultiplier.*reserved"),
    ],
)
def test_parameters_reject_reserved_and_out_of_range(data, match):
    with pytest.raises(CodecError, match=match):
        decode(frame(0x18FF23A6, data))


# --- round trips for every message ----------------------------------------------------------


def _random_payloads(rnd: random.Random):
    sw = list(Switch)
    yield PositionCounts(*(rnd.randrange(1022) for _ in ACTUATORS))
    yield PositionMeasurement(*(rnd.choice([None, rnd.randrange(1022)]) for _ in range(4)), rnd.randrange(256))
    yield PressureMeasurement(*(rnd.choice([None, rnd.randrange(64256) * 1000.0]) for _ in range(4)))
    yield EcuParameters(
        rnd.choice([None, True, False]),
        rnd.choice([None, rnd.randrange(1, 251) / 100]),
        tuple(rnd.choice([None, rnd.randrange(251) * 0.005]) for _ in ACTUATORS),
    )
    yield MeasuredPose(*(rnd.uniform(-3.2, 3.2) for _ in range(4)))
    yield RearHitchStatus(
        rnd.randrange(251) * 0.004,
        rnd.choice(sw),
        rnd.choice(list(LimitStatus)),
        rnd.randrange(251) * 0.008 - 1,
        rnd.randrange(64256) * 10.0 - 320000,
        rnd.choice([None, rnd.randrange(62)]),
    )
    yield WheelBasedSpeed(
        rnd.randrange(64256) * 0.001,
        rnd.randrange(4211081216) * 0.001,
        rnd.randrange(251) * 60.0,
        rnd.choice(list(MachineDirection)),
        rnd.choice(sw),
        rnd.choice(sw),
        rnd.choice(sw),
    )
    yield Heartbeat(rnd.choice(list(range(252)) + [254, 255]))

    def axis() -> JoystickAxis:
        return JoystickAxis(
            rnd.choice([None, rnd.randrange(1001) / 1000]),
            rnd.choice(sw),
            rnd.choice(sw),
            Switch.OFF,
            rnd.choice(sw),
        )

    yield BasicJoystick(axis(), axis(), tuple(rnd.choice(sw) for _ in range(12)))
    yield AddressClaimed(rnd.randrange(1 << 64))
    yield RequestPgn(rnd.randrange(1 << 18))


def _close(a, b, tol):
    if isinstance(a, tuple):
        return all(_close(x, y, tol) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, abs_tol=tol)
    if hasattr(a, "__dataclass_fields__"):
        return all(_close(getattr(a, k), getattr(b, k), tol) for k in a.__dataclass_fields__)
    return a == b


def test_every_message_round_trips():
    rnd = random.Random(20120612)
    seen = set()
    for _ in range(200):
        for payload in _random_payloads(rnd):
            msg = encode(payload)
            back = decode(msg)
            seen.add(type(payload))
            # within half a resolution step (finest: 0.1 mm / 0.1 mrad pose)
            assert type(back) is type(payload) and _close(back, payload, 0.5e-4), (payload, back)
            assert bytes(encode(back).data) == bytes(msg.data)  # re-encoding is stable
    assert len(seen) == 11


def test_every_dbc_message_has_a_payload_type():
    codec = load_codec()
    names = {m.name for m in codec.database.messages}
    assert len(names) == 16
    for m in codec.database.messages:
        assert m.is_extended_frame and m.protocol == "j1939"


# --- malformed frames and bad inputs ----------------------------------------------------------


@pytest.mark.parametrize(
    ("msg", "match"),
    [
        (frame(0x0CFF22A9, HAND_FF22[:7]), r"PositionMeasurement: DLC 7 .* expected 8"),
        (frame(0x18FF24A9, bytes(8)), r"unknown PGN 0x0FF24"),
        (frame(0x18FECA00, bytes(8)), r"unknown PGN 0x0FECA"),
        (can.Message(arbitration_id=0x123, is_extended_id=False, data=bytes(8)), "11-bit id"),
        (frame(0x0CFF22A9, b"", is_remote_frame=True, dlc=8), "remote frame"),
        (frame(0x18EAFFA6, bytes(5)), r"RequestPGN: DLC 5 .* expected 3 or 8"),
    ],
)
def test_malformed_frames_are_rejected_with_a_reason(msg, match):
    with pytest.raises(CodecError, match=match):
        decode(msg)


@pytest.mark.parametrize(
    ("payload", "match"),
    [
        (EcuParameters(watchdog_timeout_s=3.0), r"EcuParameters\.watchdog_timeout_s = 3\.0 outside 0\.01\.\.2\.5 s"),
        (EcuParameters(watchdog_timeout_s=0.0), r"watchdog_timeout_s = 0\.0 outside"),
        (EcuParameters(controllers_enabled=1), "must be True, False or None"),
        (MeasuredPose(x_m=float("nan")), r"MeasuredPose\.x_m must be finite"),
        (MeasuredPose(x_m=4.0), r"MeasuredPose\.x_m = 4\.0 outside -3\.2\.\.3\.2255 m"),
        (RearHitchStatus(position=1.01), r"RearHitchStatus\.position = 1\.01 outside 0\.\.1"),
        (RearHitchStatus(limit_status=5), "is not a LimitStatus"),
        (PressureMeasurement(lift_pa=-1000.0), r"lift_pa = -1000\.0 outside 0\.\.6\.4255e\+07 Pa"),
        (PositionMeasurement(1.5, 0, 0, 0), "must be an integer"),
        (PositionMeasurement(0, 0, 0, 0, system_state=None), "system_state is required"),
    ],
)
def test_encoding_rejects_out_of_range_input(payload, match):
    with pytest.raises(CodecError, match=match):
        encode(payload)


def test_encoding_rejects_a_destination_for_broadcast_messages_and_unknown_types():
    with pytest.raises(CodecError, match="destination_address must be 255"):
        encode(Heartbeat(0), destination=169)
    with pytest.raises(CodecError, match="no CAN message for str"):
        encode("hello")


def test_codec_error_is_a_value_error():
    assert issubclass(CodecError, ValueError)


# --- a user trial: bare errors, a wrong range in a refusal, an int for a float, numpy integers refused ------------


@pytest.mark.parametrize("bad", [None, b"\x00\x01\x02", bytearray(8), "0CFE4566#00"])
def test_decoding_something_that_is_no_can_message_says_so(bad):
    """``decode(None)`` and ``decode(b"...")`` failed as "has no attribute 'is_extended_id'"."""
    for call in (decode, decode_frame, load_codec().decode):
        with pytest.raises(CodecError, match=rf"a can\.Message is expected .* got {type(bad).__name__}"):
            call(bad)


@pytest.mark.parametrize("code", [62, 63, 64])
def test_an_exit_reason_code_is_refused_naming_the_codes_allowed(code):
    """0..61 may be sent (62 is "error", 63 "not available"); the refusal said "outside 0..63", the DBC range."""
    with pytest.raises(CodecError, match=rf"RearHitchStatus\.exit_reason_code = {code} outside 0\.\.61$"):
        encode(RearHitchStatus(exit_reason_code=code))
    assert decode(encode(RearHitchStatus(exit_reason_code=61))).exit_reason_code == 61


def test_a_scaled_value_decodes_as_a_float():
    """``lift_pa`` (annotated float | None) decoded as int 1000: the DBC factor 1000 is an integer."""
    got = decode(encode(PressureMeasurement(lift_pa=1000.0, supply_pa=20e6)))
    assert type(got.lift_pa) is float and got.lift_pa == 1000.0
    assert type(got.supply_pa) is float and got.supply_pa == 20e6
    assert got.tilt_pa is None


def test_counts_may_be_numpy_integers():
    """``PositionCounts(*SensorScaling(profile).to_counts(q))`` was refused: "must be an integer in 0..1021, got
    np.int64(140)". Any integer (numbers.Integral) is taken, kept as int; a bool or a float is not."""
    import numpy as np

    from planner import HitchModel, SensorScaling

    m = HitchModel.from_profile()
    counts = SensorScaling(m.profile).to_counts(m.neutral)
    pc = PositionCounts(*counts)
    assert pc.as_tuple() == tuple(int(c) for c in counts) and all(type(c) is int for c in pc.as_tuple())
    assert decode(encode_position_reference(pc)) == pc
    assert Heartbeat(np.uint8(7)).sequence == 7 and type(Heartbeat(np.uint8(7)).sequence) is int
    assert decode(encode(PositionMeasurement(np.int32(5), np.int64(6), 7, 8))).top_counts == 6
    with pytest.raises(
        CodecError, match=r"PositionCounts\.lift must be an integer in 0\.\.1021, got np\.int64\(1022\)"
    ):
        PositionCounts(np.int64(1022), 0, 0, 0, 0)
    with pytest.raises(CodecError, match=r"must be an integer in 0\.\.1021, got True"):
        PositionCounts(True, 0, 0, 0, 0)
    with pytest.raises(CodecError, match=r"must be an integer in 0\.\.1021, got np\.float64\(140\.0\)"):
        PositionCounts(np.float64(140.0), 0, 0, 0, 0)
