"""Slope sensor (SSI 61459, SSI2 61481) and implement sensor messages against their published layouts.

Independent truth: the byte layouts of the public manual Axiomatic UMAX0608XX-1000 "Tri-Axial J1939
CAN Inclinometer" v9B, sections 2.5.1.1 (SSI: bytes 1-2 pitch, 3-4 roll, 5-6 pitch rate, 0.002
deg/bit offset -64 deg, little-endian; byte 7 four 2-bit status fields; byte 8 latency 0.5 ms/bit)
and 2.5.1.2 (SSI2: 3-byte angles 1/32768 deg/bit offset -250 deg), packed here by hand.
"""

import math
import random

import can
import pytest

from bridge.isobus.codec import (
    CodecError,
    FigureOfMerit,
    GroundDistance,
    RowGuidance,
    SlopeSensorInformation,
    SlopeSensorInformation2,
    decode,
    decode_frame,
    encode,
    load_codec,
)
from bridge.isobus.j1939 import Switch, decode_id
from bridge.isobus.messages import (
    PGN_GROUND_DISTANCE,
    PGN_ROW_GUIDANCE,
    PGN_SLOPE_SENSOR_INFORMATION,
    PGN_SLOPE_SENSOR_INFORMATION_2,
    SLOPE_SENSOR_ADDRESS,
)

SSI_ID = 0x0CF013E2  # priority 3, PGN 0xF013, source 226


def frame(can_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=can_id, is_extended_id=True, data=data)


def ssi_bytes(pitch_raw, roll_raw, rate_raw, pitch_fom, roll_fom, rate_fom, comp, latency_raw) -> bytes:
    """Hand packer after the manual's table: start positions 1-2, 3-4, 5-6 (LSB first), 7.1, 7.3, 7.5, 7.7, 8."""
    status = pitch_fom | roll_fom << 2 | rate_fom << 4 | comp << 6
    return (
        pitch_raw.to_bytes(2, "little")
        + roll_raw.to_bytes(2, "little")
        + rate_raw.to_bytes(2, "little")
        + bytes([status, latency_raw])
    )


def test_pgn_numbers_and_the_default_identifier():
    assert (PGN_SLOPE_SENSOR_INFORMATION, PGN_SLOPE_SENSOR_INFORMATION_2) == (0xF013, 0xF029)
    assert (PGN_GROUND_DISTANCE, PGN_ROW_GUIDANCE) == (0xFF26, 0xFF27)
    msg = encode(SlopeSensorInformation(pitch_rad=0.0))
    ident = decode_id(msg.arbitration_id)
    assert msg.arbitration_id == SSI_ID and msg.dlc == 8
    assert (ident.pgn, ident.priority, ident.source_address) == (61459, 3, SLOPE_SENSOR_ADDRESS)


def test_hand_encoded_frame_decodes_to_the_right_angles():
    # pitch +1.000 deg -> (1 + 64) / 0.002 = 32500; roll -2.500 deg -> 30750; rate +0.5 deg/s -> 32250
    data = ssi_bytes(32500, 30750, 32250, 0, 1, 0, 1, 20)
    d = decode_frame(frame(SSI_ID, data))
    p = d.payload
    assert isinstance(p, SlopeSensorInformation)
    assert p.pitch_rad == pytest.approx(math.radians(1.0), abs=1e-12)
    assert p.roll_rad == pytest.approx(math.radians(-2.5), abs=1e-12)
    assert p.pitch_rate_rad_s == pytest.approx(math.radians(0.5), abs=1e-12)
    assert p.pitch_merit is FigureOfMerit.FULLY_FUNCTIONAL and p.roll_merit is FigureOfMerit.DEGRADED
    assert p.pitch_rate_merit is FigureOfMerit.FULLY_FUNCTIONAL and p.compensated is Switch.ON
    assert p.latency_s == pytest.approx(0.010)
    assert d.unavailable == () and d.errors == ()
    # and the encoder produces exactly these bytes
    assert bytes(encode(p).data) == data


def test_resolution_offset_and_range_ends():
    lsb = math.radians(0.002)
    for raw, deg in [(0, -64.0), (32000, 0.0), (32001, 0.002), (64255, 64.51)]:
        p = decode(frame(SSI_ID, ssi_bytes(raw, raw, raw, 0, 0, 0, 0, 0)))
        assert isinstance(p, SlopeSensorInformation)
        assert p.pitch_rad == pytest.approx(math.radians(deg), abs=1e-12)
        assert p.roll_rad == pytest.approx(math.radians(deg), abs=1e-12)
        assert p.pitch_rate_rad_s == pytest.approx(math.radians(deg), abs=1e-12)
    # encoding rounds to the nearest 0.002 deg
    m = encode(SlopeSensorInformation(pitch_rad=0.4 * lsb, roll_rad=0.6 * lsb))
    assert int.from_bytes(m.data[0:2], "little") == 32000
    assert int.from_bytes(m.data[2:4], "little") == 32001
    assert m.data[7] == 0xFF  # latency not available


def test_not_available_and_error_indicators_become_none_never_nan():
    data = ssi_bytes(0xFFFF, 0xFE00, 0xFFFF, 3, 2, 3, 3, 0xFF)
    d = decode_frame(frame(SSI_ID, data))
    p = d.payload
    assert isinstance(p, SlopeSensorInformation)
    assert p.pitch_rad is None and p.roll_rad is None and p.pitch_rate_rad_s is None and p.latency_s is None
    assert set(d.unavailable) == {"SsiPitchAngle", "SsiPitchRate", "SsiMeasurementLatency"}
    assert d.errors == ("SsiRollAngle",)
    assert p.pitch_merit is FigureOfMerit.NOT_AVAILABLE and p.roll_merit is FigureOfMerit.ERROR
    # None encodes as not available (0xFFFF), the default payload is all "not available"
    assert bytes(encode(SlopeSensorInformation()).data) == b"\xff" * 8


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (ssi_bytes(32000, 32000, 32000, 0, 0, 0, 0, 0)[:7], r"SlopeSensorInformation: DLC 7 .* expected 8"),
        (ssi_bytes(0xFB00, 32000, 32000, 0, 0, 0, 0, 0), r"SsiPitchAngle .*reserved"),
        (ssi_bytes(32000, 32000, 32000, 0, 0, 0, 0, 251), r"SsiMeasurementLatency .*reserved"),
    ],
)
def test_malformed_frames_are_rejected_naming_the_signal(data, match):
    with pytest.raises(CodecError, match=match):
        decode(frame(SSI_ID, data))


@pytest.mark.parametrize(
    ("payload", "match"),
    [
        (SlopeSensorInformation(pitch_rad=1.2), r"pitch_rad = 1.2 outside -1.117.*rad \(-64..64.51 deg on the wire\)"),
        (SlopeSensorInformation(roll_rad=math.nan), r"roll_rad must be finite"),
        (SlopeSensorInformation(pitch_rate_rad_s="0"), r"pitch_rate_rad_s must be a number"),  # type: ignore[arg-type]
        (SlopeSensorInformation(latency_s=0.2), r"latency_s = 0.2 outside 0..0.125 s"),
        (SlopeSensorInformation(pitch_merit=7), r"pitch_merit: 7 is not a FigureOfMerit"),  # type: ignore[arg-type]
        (GroundDistance(distance_m=-0.01), r"distance_m = -0.01 outside 0..6.4255 m"),
        (RowGuidance(offset_m=3.3), r"offset_m = 3.3 outside -3.2..3.2255 m"),
    ],
)
def test_out_of_range_payloads_are_refused_naming_field_and_range(payload, match):
    with pytest.raises(CodecError, match=match):
        encode(payload)


def test_ssi2_hand_encoded_frame_from_the_extended_range_layout():
    # pitch +10 deg -> (10 + 250) * 32768 = 8519680; roll -45.5 deg -> 204.5 * 32768 = 6701056
    status = 1 | 0 << 2 | 1 << 4 | 1 << 6  # pitch compensation on, pitch FOM ok, roll comp on, roll FOM degraded
    data = (8519680).to_bytes(3, "little") + (6701056).to_bytes(3, "little") + bytes([status, 20])
    m = frame(0x0CF029E2, data)
    p = decode(m)
    assert isinstance(p, SlopeSensorInformation2)
    assert p.pitch_rad == pytest.approx(math.radians(10.0), abs=1e-12)
    assert p.roll_rad == pytest.approx(math.radians(-45.5), abs=1e-12)
    assert p.pitch_compensated is Switch.ON and p.pitch_merit is FigureOfMerit.FULLY_FUNCTIONAL
    assert p.roll_compensated is Switch.ON and p.roll_merit is FigureOfMerit.DEGRADED
    assert p.latency_s == pytest.approx(0.010)
    assert bytes(encode(p).data) == data
    na = decode_frame(frame(0x0CF029E2, b"\xff" * 8))
    assert isinstance(na.payload, SlopeSensorInformation2) and na.payload.pitch_rad is None
    assert "Ssi2PitchAngle" in na.unavailable


def test_implement_sensor_layouts():
    g = encode(GroundDistance(0.4321, FigureOfMerit.FULLY_FUNCTIONAL))
    assert g.arbitration_id == 0x18FF26E3
    assert bytes(g.data) == (4321).to_bytes(2, "little") + bytes([0b11111100]) + b"\xff" * 5
    r = encode(RowGuidance(-0.0125, FigureOfMerit.DEGRADED))
    assert r.arbitration_id == 0x18FF27E4
    assert bytes(r.data) == (31875).to_bytes(2, "little") + bytes([0b11111101]) + b"\xff" * 5
    assert decode(frame(0x18FF27E4, b"\xff" * 8)) == RowGuidance(None, FigureOfMerit.NOT_AVAILABLE)


def test_random_round_trips_stay_within_half_a_step():
    rnd = random.Random(61459)
    half_deg = math.radians(0.001)
    foms = list(FigureOfMerit)
    sw = list(Switch)
    for _ in range(300):
        p = SlopeSensorInformation(
            pitch_rad=rnd.uniform(-1.117, 1.125),
            roll_rad=rnd.uniform(-1.117, 1.125),
            pitch_rate_rad_s=rnd.choice([None, rnd.uniform(-1.1, 1.1)]),
            pitch_merit=rnd.choice(foms),
            roll_merit=rnd.choice(foms),
            pitch_rate_merit=rnd.choice(foms),
            compensated=rnd.choice(sw),
            latency_s=rnd.randrange(251) / 2000,
        )
        back = decode(encode(p))
        assert isinstance(back, SlopeSensorInformation)
        assert back.pitch_rad == pytest.approx(p.pitch_rad, abs=half_deg + 1e-12)
        assert back.roll_rad == pytest.approx(p.roll_rad, abs=half_deg + 1e-12)
        if p.pitch_rate_rad_s is None:
            assert back.pitch_rate_rad_s is None
        else:
            assert back.pitch_rate_rad_s == pytest.approx(p.pitch_rate_rad_s, abs=half_deg + 1e-12)
        assert (back.pitch_merit, back.roll_merit, back.pitch_rate_merit, back.compensated) == (
            p.pitch_merit,
            p.roll_merit,
            p.pitch_rate_merit,
            p.compensated,
        )
        assert back.latency_s == pytest.approx(p.latency_s)
        p2 = SlopeSensorInformation2(pitch_rad=rnd.uniform(-3.1, 3.1), roll_rad=rnd.uniform(-3.1, 3.1))
        b2 = decode(encode(p2))
        assert isinstance(b2, SlopeSensorInformation2)
        assert b2.pitch_rad == pytest.approx(p2.pitch_rad, abs=math.radians(0.5 / 32768) + 1e-12)


def test_the_dbc_units_are_those_of_the_definition():
    db = load_codec().database
    ssi = db.get_message_by_name("SlopeSensorInformation")
    units = {s.name: (s.start, s.length, s.scale, s.offset, s.unit) for s in ssi.signals}
    assert units["SsiPitchAngle"] == (0, 16, 0.002, -64, "deg")
    assert units["SsiRollAngle"] == (16, 16, 0.002, -64, "deg")
    assert units["SsiPitchRate"] == (32, 16, 0.002, -64, "deg/s")
    assert units["SsiMeasurementLatency"] == (56, 8, 0.5, 0, "ms")
    assert "Axiomatic UMAX0608XX-1000" in (ssi.comment or "")
