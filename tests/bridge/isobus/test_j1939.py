"""29-bit identifiers, PGNs, J1939 raw ranges and bus load against hand-computed truth."""

import random

import cantools.j1939
import pytest

from bridge.isobus.j1939 import (
    GLOBAL_ADDRESS,
    PGN_HEARTBEAT,
    RawStatus,
    bus_load,
    classify_raw,
    decode_id,
    encode_id,
    frame_bits,
    largest_valid_raw,
)


def test_thesis_joystick_id_is_pdu2_pgn_fdd6_from_5_priority_3():
    ident = decode_id(0x0CFDD605)
    assert ident.priority == 3
    assert ident.pgn == 0xFDD6
    assert ident.source_address == 0x05
    assert not ident.is_pdu1
    assert ident.pdu_format == 0xFD and ident.pdu_specific == 0xD6
    assert ident.destination_address == GLOBAL_ADDRESS
    assert ident.data_page == 0 and ident.extended_data_page == 0
    assert encode_id(0xFDD6, 0x05, priority=3) == 0x0CFDD605


def test_pdu1_request_carries_destination_outside_the_pgn():
    # Request (PGN 59904 = 0xEA00) from 166 (0xA6) to the cylinder ECU 169 (0xA9), priority 6:
    # 6 << 26 | 0xEA << 16 | 0xA9 << 8 | 0xA6 written out by hand:
    assert encode_id(0xEA00, 166, priority=6, destination_address=169) == 0x18EAA9A6
    ident = decode_id(0x18EAA9A6)
    assert ident.is_pdu1
    assert ident.pgn == 0xEA00
    assert ident.destination_address == 169
    assert ident.source_address == 166
    # Same PGN to the global address.
    assert decode_id(0x18EAFFA6).pgn == 0xEA00
    assert decode_id(0x18EAFFA6).destination_address == GLOBAL_ADDRESS


def test_pdu_format_240_is_the_first_pdu2_value():
    hb = decode_id(0x0CF0E4A6)  # heartbeat, PF 0xF0 = 240
    assert not hb.is_pdu1 and hb.pgn == PGN_HEARTBEAT == 0xF0E4
    last_pdu1 = decode_id(0x18EF12A6)  # PF 239: PS 0x12 is a destination
    assert last_pdu1.is_pdu1 and last_pdu1.pgn == 0xEF00 and last_pdu1.destination_address == 0x12


def test_data_page_and_extended_data_page_enter_the_pgn():
    ident = decode_id(encode_id(0x3FF21, 7, priority=7))
    assert ident.extended_data_page == 1 and ident.data_page == 1
    assert ident.pgn == 0x3FF21
    assert ident.can_id == (7 << 26) | (1 << 25) | (1 << 24) | (0xFF << 16) | (0x21 << 8) | 7


def test_identifier_fields_agree_with_cantools_j1939_on_random_ids():
    rnd = random.Random(11783)
    for _ in range(2000):
        can_id = rnd.randrange(1 << 29)
        ours = decode_id(can_id)
        theirs = cantools.j1939.frame_id_unpack(can_id)
        assert (
            ours.priority,
            ours.extended_data_page,
            ours.data_page,
            ours.pdu_format,
            ours.pdu_specific,
            ours.source_address,
        ) == tuple(theirs)
        assert ours.pgn == cantools.j1939.pgn_from_frame_id(can_id)
        assert ours.can_id == can_id


def test_encode_decode_round_trip_on_random_fields():
    rnd = random.Random(7)
    for _ in range(2000):
        pf = rnd.randrange(256)
        pdu1 = pf < 240
        pgn = (rnd.randrange(4) << 16) | (pf << 8) | (0 if pdu1 else rnd.randrange(256))
        dest = rnd.randrange(256) if pdu1 else GLOBAL_ADDRESS
        sa, prio = rnd.randrange(256), rnd.randrange(8)
        ident = decode_id(encode_id(pgn, sa, priority=prio, destination_address=dest))
        assert (ident.pgn, ident.source_address, ident.priority, ident.destination_address) == (pgn, sa, prio, dest)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(pgn=0xEA05, source_address=1), "low byte must be 0"),
        (dict(pgn=0xFF21, source_address=1, destination_address=169), "destination_address must be 255"),
        (dict(pgn=0xFF21, source_address=1, priority=8), r"priority must be in 0\.\.7"),
        (dict(pgn=0x40000, source_address=1), r"pgn must be in 0\.\.262143"),
        (dict(pgn=0xFF21, source_address=256), r"source_address must be in 0\.\.255"),
        (dict(pgn=0xFF21, source_address=True), "source_address must be an integer"),
    ],
)
def test_encode_id_rejects_bad_fields_with_named_ranges(kwargs, match):
    with pytest.raises(ValueError, match=match):
        encode_id(**kwargs)


def test_decode_id_rejects_more_than_29_bits():
    with pytest.raises(ValueError, match="can_id must be in 0..536870911"):
        decode_id(1 << 29)


@pytest.mark.parametrize(
    ("raw", "length", "status"),
    [
        (250, 8, RawStatus.VALID),
        (251, 8, RawStatus.RESERVED),
        (253, 8, RawStatus.RESERVED),
        (254, 8, RawStatus.ERROR),
        (255, 8, RawStatus.NOT_AVAILABLE),
        (0xFAFF, 16, RawStatus.VALID),
        (0xFB00, 16, RawStatus.RESERVED),
        (0xFE12, 16, RawStatus.ERROR),
        (0xFF00, 16, RawStatus.NOT_AVAILABLE),
        (0xFAFFFFFF, 32, RawStatus.VALID),
        (0xFF000000, 32, RawStatus.NOT_AVAILABLE),
        (1021, 10, RawStatus.VALID),
        (1022, 10, RawStatus.ERROR),
        (1023, 10, RawStatus.NOT_AVAILABLE),
        (1, 2, RawStatus.VALID),
        (2, 2, RawStatus.ERROR),
        (3, 2, RawStatus.NOT_AVAILABLE),
        (61, 6, RawStatus.VALID),
        (62, 6, RawStatus.ERROR),
        (63, 6, RawStatus.NOT_AVAILABLE),
        (1, 1, RawStatus.VALID),
    ],
)
def test_j1939_transmitted_signal_ranges(raw, length, status):
    assert classify_raw(raw, length) is status


def test_classify_raw_rejects_a_value_wider_than_its_field():
    with pytest.raises(ValueError, match=r"raw must be in 0\.\.1023"):
        classify_raw(1024, 10)


def test_frame_bits_match_the_davis_worst_case_formulas():
    # Davis et al. 2007: extended frame (80 + 10 n) bits, standard (55 + 10 n) bits worst case.
    for n in range(9):
        assert frame_bits(n) == 80 + 10 * n
        assert frame_bits(n, extended=False) == 55 + 10 * n
    # Without stuffing: 64 overhead + 3 interframe + 8 per byte.
    assert frame_bits(8, worst_case_stuffing=False) == 131


def test_bus_load_of_the_default_traffic_hand_computed():
    # Reference 50 Hz + measurement 100 Hz + hitch status 10 Hz + two heartbeats 10 Hz each,
    # all DLC 8 -> 180 frames/s * 160 bit = 28 800 bit/s of 250 000 -> 11.52 %.
    assert bus_load({8: 50 + 100 + 10 + 2 * 10}) == pytest.approx(0.1152, abs=1e-12)
    # Nominal (no stuffing): 180 * 131 / 250 000.
    assert bus_load({8: 180}, worst_case_stuffing=False) == pytest.approx(0.09432, abs=1e-12)
    # Mixed DLCs add up: a request (DLC 3, 110 bits) at 1 Hz on top.
    assert bus_load({8: 180, 3: 1}) == pytest.approx((28_800 + 110) / 250_000, abs=1e-12)


@pytest.mark.parametrize(
    ("traffic", "kwargs", "match"),
    [
        ({9: 1.0}, {}, r"dlc must be in 0\.\.8"),
        ({8: -1.0}, {}, "frames per second for dlc 8"),
        ({8: float("nan")}, {}, "frames per second for dlc 8"),
        ({8: 1.0}, {"bitrate_bps": 0}, "bitrate_bps must be a positive"),
    ],
)
def test_bus_load_rejects_bad_input(traffic, kwargs, match):
    with pytest.raises(ValueError, match=match):
        bus_load(traffic, **kwargs)


@pytest.mark.parametrize("length", [1, 2, 6, 8, 10, 16, 32])
def test_largest_valid_raw_is_the_last_one_classify_raw_calls_valid(length):
    top = largest_valid_raw(length)
    assert classify_raw(top, length) is RawStatus.VALID
    assert top == (1 << length) - 1 or classify_raw(top + 1, length) is not RawStatus.VALID
