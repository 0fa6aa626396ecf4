"""The codec's memo of repeated frames gives exactly what encoding and decoding anew give."""

import random

import can
import pytest

from bridge.isobus.codec import (
    Codec,
    CodecError,
    Heartbeat,
    PositionCounts,
    PositionMeasurement,
    RearHitchStatus,
    load_codec,
)
from bridge.isobus.j1939 import (
    CYLINDER_ECU_ADDRESS,
    PGN_HEARTBEAT,
    PGN_POSITION_MEASUREMENT,
    PGN_POSITION_REFERENCE,
    PGN_REAR_HITCH_STATUS,
    PGN_WHEEL_BASED_SPEED,
    PLANNER_ADDRESS,
    TRACTOR_ECU_ADDRESS,
    encode_id,
)
from tests.bridge.isobus.test_codec import _random_payloads


@pytest.fixture
def codec() -> Codec:
    return Codec(load_codec().database)  # a codec of its own: an empty memo


def _fields(msg: can.Message) -> tuple:
    return (msg.arbitration_id, msg.is_extended_id, msg.dlc, bytes(msg.data), msg.is_error_frame, msg.is_remote_frame)


def test_memoised_encoding_equals_encoding_anew_on_random_payloads(codec):
    rnd = random.Random(7)
    payloads = [p for _ in range(60) for p in _random_payloads(rnd)]
    for payload in payloads + payloads[::-1]:  # every payload twice: the second is a memo hit or a re-encode
        fresh = codec._encode(payload, None, 255, None)
        first, again = codec.encode(payload), codec.encode(payload)
        assert _fields(first) == _fields(again) == _fields(fresh)
        assert first is not again  # a new frame each time: callers may own and change it


def test_memoised_decoding_equals_decoding_anew_on_random_frames(codec):
    rnd = random.Random(11)
    hot = [  # the frames of a hitch at rest, each with random data
        (PGN_POSITION_MEASUREMENT, CYLINDER_ECU_ADDRESS, 8),
        (PGN_REAR_HITCH_STATUS, CYLINDER_ECU_ADDRESS, 8),
        (PGN_POSITION_REFERENCE, PLANNER_ADDRESS, 8),
        (PGN_WHEEL_BASED_SPEED, TRACTOR_ECU_ADDRESS, 8),
        (PGN_HEARTBEAT, CYLINDER_ECU_ADDRESS, 8),
    ]
    frames = []
    for _ in range(400):
        pgn, src, n = rnd.choice(hot)
        data = bytes(rnd.randrange(256) for _ in range(n if rnd.random() < 0.9 else rnd.randrange(n)))
        if rnd.random() < 0.5 and frames:  # repeats, as at rest
            prev = rnd.choice(frames)
            frames.append(can.Message(arbitration_id=prev.arbitration_id, is_extended_id=True, data=prev.data))
            continue
        frames.append(can.Message(arbitration_id=encode_id(pgn, src, priority=3), is_extended_id=True, data=data))
    decoded = rejected = 0
    for i, msg in enumerate(frames):
        msg.timestamp = 1000.0 + i
        try:
            fresh = codec._decode_frame(msg)
        except CodecError as exc:
            with pytest.raises(CodecError) as got:
                codec.decode_frame(msg)
            assert str(got.value) == str(exc)
            rejected += 1
            continue
        for _ in range(2):
            assert codec.decode_frame(msg) == fresh  # same ident, payload, lists and this frame's timestamp
        decoded += 1
    assert decoded > 100 and rejected > 20  # both paths exercised


def test_a_frame_that_fails_fails_every_time_and_a_wrong_typed_argument_is_never_served_from_the_memo(codec):
    counts = PositionCounts(100, 200, 300, 400, 500)
    codec.encode(counts, source=1)
    with pytest.raises(CodecError):
        codec.encode(counts, source=True)  # equal to 1 as a key, still refused as on the first call
    bad = can.Message(
        arbitration_id=encode_id(PGN_POSITION_MEASUREMENT, CYLINDER_ECU_ADDRESS), is_extended_id=True, data=b"\x00" * 3
    )
    for _ in range(2):
        with pytest.raises(CodecError, match="DLC"):
            codec.decode_frame(bad)


def test_the_memo_stays_bounded(codec):
    for i in range(1000):
        codec.decode_frame(codec.encode(PositionMeasurement(i % 1000, 1, 2, 3)))
        codec.encode(RearHitchStatus(position=(i % 251) * 0.004))
        codec.encode(Heartbeat(i % 252))
    assert len(codec._encoded) <= 64 and len(codec._decoded) <= 64
