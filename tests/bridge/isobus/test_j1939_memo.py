"""decode_id's memo: repeated identifiers decode to exactly the fields computed from the bits."""

import random

import pytest

from bridge.isobus.j1939 import J1939Error, decode_id


def test_decode_id_equals_the_bit_fields_on_random_ids_repeated_and_refuses_bad_ones_every_time():
    rnd = random.Random(3)
    ids = [rnd.randrange(1 << 29) for _ in range(40)]
    for can_id in [rnd.choice(ids) for _ in range(2000)] + [rnd.randrange(1 << 29) for _ in range(600)]:
        d = decode_id(can_id)
        truth = (
            (can_id >> 26) & 7,
            (can_id >> 25) & 1,
            (can_id >> 24) & 1,
            (can_id >> 16) & 0xFF,
            (can_id >> 8) & 0xFF,
            can_id & 0xFF,
        )
        assert (
            d.priority,
            d.extended_data_page,
            d.data_page,
            d.pdu_format,
            d.pdu_specific,
            d.source_address,
        ) == truth
        assert d.can_id == can_id
    decode_id(1)
    for _ in range(2):  # equal to 1 as a key, still refused; out of range always refused
        with pytest.raises(J1939Error):
            decode_id(True)
        with pytest.raises(J1939Error):
            decode_id(1 << 29)
