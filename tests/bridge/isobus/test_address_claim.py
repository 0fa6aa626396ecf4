"""NAME encoding and the address-claim state machine (claim, 250 ms, contention, cannot claim)."""

import random

import can
import pytest

from bridge.isobus.address_claim import (
    AddressClaimer,
    ClaimState,
    Name,
    cylinder_ecu_name,
    planner_name,
)
from bridge.isobus.codec import AddressClaimed, RequestPgn, decode, encode


def claim_frame(name: Name, source: int) -> can.Message:
    return encode(AddressClaimed(name.value), source=source)


def request_claims(source: int = 0x80, destination: int = 255) -> can.Message:
    return encode(RequestPgn(0xEE00), source=source, destination=destination)


def test_planner_name_bits_hand_computed():
    name = planner_name(identity_number=1)
    # identity 1 (bits 0-20), function 130 (bits 40-47), vehicle system 1 "tractor"
    # (bits 49-55), industry group 2 "agricultural" (bits 60-62), not arbitrary capable.
    assert name.value == 1 + (130 << 40) + (1 << 49) + (2 << 60)
    assert bytes(claim_frame(name, 166).data) == bytes.fromhex("0100000000820220")
    assert (name.function, name.vehicle_system, name.industry_group) == (130, 1, 2)


def test_name_round_trips_and_agrees_with_the_dbc_fields():
    rnd = random.Random(81)
    for _ in range(500):
        value = rnd.randrange(1 << 64)
        name = Name.from_int(value)
        assert name.value == value
        msg = claim_frame(name, 166)
        assert bytes(msg.data) == value.to_bytes(8, "little")
        assert decode(msg) == AddressClaimed(value)
    name = Name(
        identity_number=0x1FFFFF,
        manufacturer_code=0x7FF,
        ecu_instance=7,
        function_instance=31,
        function=255,
        vehicle_system=127,
        vehicle_system_instance=15,
        industry_group=7,
        arbitrary_address_capable=True,
    )
    assert name.value == 0xFFFE_FFFF_FFFF_FFFF  # everything but the reserved bit 48
    signals = decode(claim_frame(name, 1))
    assert signals.name == name.value


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(identity_number=1 << 21), r"identity_number must be an integer in 0\.\.2097151"),
        (dict(identity_number=1, function=256), r"function must be an integer in 0\.\.255"),
        (dict(identity_number=1, industry_group=8), r"industry_group must be an integer in 0\.\.7"),
        (dict(identity_number=1, arbitrary_address_capable=1), "must be a bool"),
    ],
)
def test_name_rejects_fields_that_do_not_fit(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Name(**kwargs)


def test_claim_without_contention_takes_250_ms():
    ac = AddressClaimer(planner_name(), 166)
    out = ac.start(10.0)
    assert len(out) == 1 and out[0].arbitration_id == 0x18EEFFA6
    assert decode(out[0]) == AddressClaimed(planner_name().value)
    assert ac.state is ClaimState.CLAIMING and not ac.claimed
    assert ac.poll(10.249) == [] and not ac.claimed
    ac.poll(10.25)
    assert ac.claimed and ac.address == 166


class Bus:
    """Delivers every frame to every other node, in order, at the time it was sent."""

    def __init__(self, nodes):
        self.nodes = nodes
        self.log = []

    def run(self, until_s, dt=0.001, t0=0.0):
        t = t0
        while t <= until_s + 1e-9:
            self.tick(t)
            t += dt

    def tick(self, t):
        """Every node's periodic frames at ``t`` (``poll``), delivered."""
        for sender in self.nodes:
            self._broadcast(sender, sender.poll(t), t)

    def _broadcast(self, sender, frames, t):
        queue = [(sender, f) for f in frames]
        while queue:
            src, f = queue.pop(0)
            self.log.append((t, src, f))
            for node in self.nodes:
                if node is not src:
                    queue.extend((node, g) for g in node.handle(f, t))

    def send(self, sender, frames, t):
        self._broadcast(sender, frames, t)


def test_contention_lower_name_wins_loser_sends_cannot_claim_from_254():
    low, high = planner_name(identity_number=5), planner_name(identity_number=9)
    assert low.value < high.value
    a, b = AddressClaimer(low, 166), AddressClaimer(high, 166)
    bus = Bus([a, b])
    bus.send(b, b.start(0.0), 0.0)  # the higher NAME claims first ...
    bus.send(a, a.start(0.1), 0.1)  # ... the lower NAME contends
    bus.run(0.6, t0=0.1)
    assert a.claimed and a.address == 166
    assert b.state is ClaimState.CANNOT_CLAIM and b.address is None
    cannot = [f for _, src, f in bus.log if src is b and f.arbitration_id == 0x18EEFFFE]
    assert len(cannot) == 1 and decode(cannot[0]) == AddressClaimed(high.value)
    # b defends nothing afterwards: a higher claim for 166 later is fought by a only.
    later = a.handle(claim_frame(planner_name(identity_number=99), 166), 1.0)
    assert [f.arbitration_id for f in later] == [0x18EEFFA6] and a.claimed


def test_winner_restarts_its_window_and_loser_with_arbitrary_address_reclaims():
    low = planner_name(identity_number=5)
    high = planner_name(identity_number=9, arbitrary_address_capable=True)
    a, b = AddressClaimer(low, 166), AddressClaimer(high, 166)
    bus = Bus([a, b])
    bus.send(a, a.start(0.0), 0.0)
    bus.send(b, b.start(0.05), 0.05)  # b loses at once: a's NAME is lower
    assert b.state is ClaimState.CLAIMING and b.address == 167
    bus.run(0.5, t0=0.05)
    assert a.claimed and a.address == 166
    assert b.claimed and b.address == 167
    assert b.peers == {166: low}


def test_lower_name_arriving_after_claim_takes_the_address():
    ac = AddressClaimer(planner_name(identity_number=50), 166)
    ac.start(0.0)
    ac.poll(0.3)
    assert ac.claimed
    out = ac.handle(claim_frame(planner_name(identity_number=3), 166), 1.0)
    assert ac.state is ClaimState.CANNOT_CLAIM
    assert [f.arbitration_id for f in out] == [0x18EEFFFE]


def test_claims_for_other_addresses_are_only_recorded():
    ac = AddressClaimer(cylinder_ecu_name(), 169)
    ac.start(0.0)
    assert ac.handle(claim_frame(planner_name(), 166), 0.1) == []
    assert ac.peers == {166: planner_name()}
    ac.poll(0.25)
    assert ac.claimed and ac.address == 169


def test_request_for_address_claim_is_answered():
    ac = AddressClaimer(planner_name(), 166)
    assert ac.handle(request_claims(), 0.0) == []  # not started: silent
    ac.start(0.0)
    for t, dest, answered in ((0.1, 255, True), (0.3, 166, True), (0.5, 169, False)):  # 0.1 s apart at least
        out = ac.handle(request_claims(destination=dest), t)
        assert len(out) == answered
        if answered:
            assert out[0].arbitration_id == 0x18EEFFA6
    other_pgn = encode(RequestPgn(0xFECA), source=0x80)
    assert ac.handle(other_pgn, 0.1) == []


def test_cannot_claim_answers_a_global_request_after_a_pseudo_random_delay():
    name = planner_name(identity_number=50)
    ac = AddressClaimer(name, 166)
    ac.start(0.0)
    ac.handle(claim_frame(planner_name(identity_number=3), 166), 0.01)
    assert ac.state is ClaimState.CANNOT_CLAIM
    assert ac.handle(request_claims(), 1.0) == []
    delay = (name.value % 154) / 1000.0
    assert 0.0 < delay <= 0.153  # this NAME gives a non-zero delay
    assert ac.poll(1.0 + delay / 2) == []
    out = ac.poll(1.0 + delay)
    assert [f.arbitration_id for f in out] == [0x18EEFFFE]
    assert decode(out[0]) == AddressClaimed(name.value)
    assert ac.poll(2.0) == []


def test_malformed_and_unrelated_frames_are_ignored():
    ac = AddressClaimer(planner_name(), 166)
    ac.start(0.0)
    short = can.Message(arbitration_id=0x18EEFFA9, is_extended_id=True, data=bytes(5))
    assert ac.handle(short, 0.1) == [] and ac.peers == {}
    std = can.Message(arbitration_id=0x123, is_extended_id=False, data=bytes(8))
    assert ac.handle(std, 0.1) == []
    hb = can.Message(arbitration_id=0x0CF0E4A9, is_extended_id=True, data=b"\x01" + b"\xff" * 7)
    assert ac.handle(hb, 0.1) == []
    assert ac.handle(claim_frame(planner_name(), 166), 0.1) == []  # own echo
    ac.poll(0.25)
    assert ac.claimed


@pytest.mark.parametrize(("address", "wait"), [(254, 0.25), (255, 0.25), (-1, 0.25), (166, 0.0)])
def test_claimer_rejects_bad_configuration(address, wait):
    with pytest.raises(ValueError, match="preferred_address|wait_s"):
        AddressClaimer(planner_name(), address, wait_s=wait)


def test_a_lost_address_is_asked_again_and_claimed_back_when_its_holder_is_silent():
    name = planner_name(identity_number=50)
    ac = AddressClaimer(name, 166, recheck_s=1.0)
    ac.start(0.0)
    ac.poll(0.3)
    lower = planner_name(identity_number=3)
    ac.handle(claim_frame(lower, 166), 0.5)
    assert ac.state is ClaimState.CANNOT_CLAIM and ac.holder == lower
    assert ac.poll(1.49) == []
    ask = ac.poll(1.5)  # a Request for Address Claimed to 166 from the null address
    assert [f.arbitration_id for f in ask] == [0x18EAA6FE] and decode(ask[0]) == RequestPgn(0xEE00)
    ac.handle(claim_frame(lower, 166), 1.6)  # the holder answers: it keeps the address
    assert ac.poll(1.8) == [] and ac.state is ClaimState.CANNOT_CLAIM and ac.holder == lower
    again = ac.poll(2.5)  # asked again a period later; nobody answers
    assert [(f.arbitration_id, bytes(f.data)) for f in again] == [(0x18EAA6FE, bytes(ask[0].data))]
    out = ac.poll(2.75)
    assert [f.arbitration_id for f in out] == [0x18EEFFA6] and ac.state is ClaimState.CLAIMING
    assert ac.holder is None
    ac.poll(3.0)
    assert ac.claimed and ac.address == 166
    assert [(f.arbitration_id, decode(f)) for f in ac.announce()] == [(0x18EEFFA6, AddressClaimed(name.value))]
    with pytest.raises(ValueError, match="recheck_s"):
        AddressClaimer(name, 166, recheck_s=0.0)


def test_without_recheck_a_lost_address_stays_lost():
    ac = AddressClaimer(planner_name(identity_number=50), 166)
    ac.start(0.0)
    ac.handle(claim_frame(planner_name(identity_number=3), 166), 0.1)
    assert all(ac.poll(0.1 * k) == [] for k in range(2, 100))
    assert ac.state is ClaimState.CANNOT_CLAIM and ac.announce() == []
