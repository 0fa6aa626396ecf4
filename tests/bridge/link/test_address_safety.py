"""The link's own source address: spoofed frames with it (address conflict, J1939-81), our own echo,
and a lost address claim that is re-checked and won back when its holder is silent."""

import can
import numpy as np
import pytest

from bridge.isobus.address_claim import AddressClaimer, ClaimState, Name
from bridge.isobus.codec import AddressClaimed, RequestPgn, decode_frame, encode
from bridge.isobus.j1939 import PGN_ADDRESS_CLAIMED, PGN_REQUEST, decode_id
from bridge.link.can_link import CanLink
from bridge.link.state import LinkFaultError
from bridge.link.virtual import InProcessBus
from planner.model.exact_inverse import ExactInverse


def drain(bus):
    out = []
    while (f := bus.recv(timeout=0.0)) is not None:
        out.append(f)
    return out


@pytest.fixture
def rival(rig):
    bus = can.Bus(interface="virtual", channel=rig.channel)
    yield bus
    bus.shutdown()


def test_spoofed_references_with_our_source_address_are_an_address_conflict_that_stops_motion(rig, rival, model):
    """Safety tester: references injected on the bus with the planner's address 166 moved the hitch and the
    link counted them as its own echo."""
    high = ExactInverse(model)(0.0, 0.3, 0.0, 0.0)
    rig.link.send_reference(model.neutral, rig.next_tick_s)
    rig.run_until(rig.now_s + 0.3)
    assert rig.link.streaming
    tap = can.Bus(interface="virtual", channel=rig.channel)
    spoof = encode(rig.link.check_reference(high), source=166)
    rival.send(spoof)
    rig.tick()
    t_spoof = rig.now_s
    assert not rig.link.streaming, "a frame with our address that we did not send must stop motion"
    assert rig.link.faults.address_conflict and rig.link.faults.active() == ("address_conflict",)
    assert "address conflict" in rig.link.faults.reasons[0] and "166" in rig.link.faults.reasons[0]
    c = rig.link.counters
    assert c.address_conflicts == 1 and c.own_echo == 0
    # J1939-81: we send our claim again, so that the other node sees the contention
    claims = [f for f in drain(tap) if decode_id(f.arbitration_id).pgn == PGN_ADDRESS_CLAIMED]
    tap.shutdown()
    assert [decode_id(f.arbitration_id).source_address for f in claims] == [166]
    assert decode_frame(claims[0]).payload == AddressClaimed(rig.link.config.name.value)
    # present while such frames arrive: a new command is refused
    rig.run_until(t_spoof + 0.5)
    rival.send(spoof)
    rig.tick()
    assert "address_conflict" in rig.link.fault_causes(rig.now_s)
    assert "address_conflict" in rig.link.status(rig.now_s).fault_causes
    with pytest.raises(LinkFaultError, match="address conflict"):
        rig.link.send_reference(model.neutral, rig.next_tick_s)
    assert rig.link.counters.address_conflicts == 2
    # gone once none has arrived for CONFLICT_HOLD_S; a fresh command streams again
    from bridge.link.can_link import CONFLICT_HOLD_S

    rig.run_until(rig.now_s + CONFLICT_HOLD_S + 0.01)
    assert rig.link.fault_causes(rig.now_s) == ()
    rig.link.send_reference(model.neutral, rig.next_tick_s)
    rig.run_until(rig.now_s + 0.1)
    assert rig.link.streaming and not rig.link.faults.any


def test_our_own_echo_is_no_conflict(model):
    """A bus with receive_own_messages (as a multicast transport would) gives us our frames back: only echoes
    of frames we sent within the echo window count as ours."""
    channel = "echo-test"
    bus = InProcessBus(channel=channel, receive_own_messages=True)
    link = CanLink(model, bus, own_bus=True)
    link.start(0.0)
    for k in range(1, 101):  # 1 s: claim, heartbeats, all echoed
        link.poll(k * 0.01)
    c = link.counters
    assert link.claimed and c.own_echo >= 10 and c.address_conflicts == 0 and not link.faults.address_conflict
    # a heartbeat of ours we did not send within the echo window (a replay, a spoof) is a conflict
    replay = can.Message(arbitration_id=0x0CF0E4A6, is_extended_id=True, data=bytes([7]) + b"\xff" * 7)
    other = InProcessBus(channel=channel)
    other.send(replay)
    link.poll(3.0)
    other.shutdown()
    assert link.counters.address_conflicts == 1 and link.faults.address_conflict
    link.close()


def _ticks_with_holder(rig, rival, holder, seconds):
    """Run the rig for ``seconds`` with ``holder`` (an AddressClaimer behind ``rival``) answering on the bus."""
    end = rig.now_s + seconds
    while rig.now_s < end - 1e-9:
        t = rig.tick()
        for frame in drain(rival):
            for out in holder.handle(frame, t):
                rival.send(out)
        for out in holder.poll(t):
            rival.send(out)


def _spoofed_claim_during_a_stream(rig, rival, model):
    rig.link.send_reference(model.neutral, rig.next_tick_s)
    rig.run_until(rig.now_s + 0.2)
    rival.send(encode(AddressClaimed(0), source=166))  # the lowest NAME there is
    rig.tick()
    assert rig.link.faults.address_lost and not rig.link.streaming
    return rig.now_s


def test_a_spoofed_address_claim_is_re_checked_and_the_address_won_back(rig, rival, model):
    """Safety tester: a spoofed Address Claimed (NAME 0, SA 166) during a move raised address_lost; after
    the acknowledge every goto was refused "not claimed" for ever. The link now asks the address again
    and, nobody answering for it, claims it back."""
    tap = can.Bus(interface="virtual", channel=rig.channel)
    t_lost = _spoofed_claim_during_a_stream(rig, rival, model)
    rig.run_until(t_lost + 2.0)  # asked at 1 s, no answer in 250 ms, claimed again, 250 ms contention
    assert rig.link.claimed, "the spoofed claimant never answered: the address is ours again"
    assert rig.link.fault_causes(rig.now_s) == ()
    frames = drain(tap)
    tap.shutdown()
    ask = [
        f
        for f in frames
        if decode_id(f.arbitration_id).pgn == PGN_REQUEST
        and decode_id(f.arbitration_id).source_address == 254
        and decode_id(f.arbitration_id).destination_address == 166
    ]
    assert len(ask) == 1 and decode_frame(ask[0]).payload == RequestPgn(PGN_ADDRESS_CLAIMED)
    # an acknowledge and a fresh command stream again
    rig.link.clear_faults(rig.now_s)
    rig.link.send_reference(model.neutral, rig.next_tick_s)
    rig.run_until(rig.now_s + 0.3)
    assert rig.link.streaming and not rig.link.faults.any


def test_while_the_address_is_held_by_another_name_the_condition_names_it(rig, rival, model):
    t_lost = _spoofed_claim_during_a_stream(rig, rival, model)
    problem = rig.link.address_problem
    assert problem.startswith("address 166 lost, not claimed: NAME 0x0000000000000000 holds it")
    assert rig.link.status(rig.now_s).address_problem == problem
    assert rig.link.status(rig.now_s).fault_causes == ("address_lost",)
    assert rig.link.fault_causes(rig.now_s) == ("address_lost",)
    assert problem in rig.link.faults.reasons
    rig.run_until(t_lost + 0.9)
    assert rig.link.fault_causes(rig.now_s) == ("address_lost",) and rig.link.address_problem == problem
    assert rig.link.clear_faults(rig.now_s).address_lost  # an acknowledge cannot clear it while true
    rig.run_until(t_lost + 2.0)
    assert rig.link.address_problem == "" and rig.link.status(rig.now_s).address_problem == ""


def test_a_real_holder_of_our_address_keeps_it_and_the_condition_stays(rig, rival, model):
    holder = AddressClaimer(Name.from_int(0), 166)
    for f in holder.start(rig.now_s):
        rival.send(f)
    _ticks_with_holder(rig, rival, holder, 0.3)
    assert holder.claimed and rig.link.faults.address_lost
    _ticks_with_holder(rig, rival, holder, 5.0)  # asked five times, answered each time
    assert not rig.link.claimed and rig.link._claimer.state is ClaimState.CANNOT_CLAIM  # noqa: SLF001
    assert "NAME 0x0000000000000000 holds it" in rig.link.address_problem
    assert rig.link.fault_causes(rig.now_s) == ("address_lost",)
    assert rig.link.counters.address_conflicts == 0  # the holder's traffic with 166 is no conflict now
    with pytest.raises(LinkFaultError, match="not claimed"):
        rig.link.send_reference(model.neutral, rig.next_tick_s)
    assert np.isfinite(rig.now_s)


def test_the_sends_kept_to_tell_our_echo_stay_within_the_echo_window_on_a_bus_that_echoes_nothing(rig, model):
    """A reviewer's finding: on a bus without echoes (the virtual bus, socketcan) the send times of a held
    pose's reference frame were never dropped (30 000 after 10 minutes of holding). Only those within the echo
    window are kept."""
    from bridge.link.can_link import ECHO_WINDOW_S

    rig.link.send_reference(model.neutral, rig.next_tick_s)
    rig.run_until(rig.now_s + 20.0)  # holding: the same frame re-sent at 50 Hz
    kept = sum(len(v) for v in rig.link._sent.values())  # noqa: SLF001 — the link's echo table
    per_s = 1.0 / rig.link.config.control_period_s
    assert kept <= 3 * (ECHO_WINDOW_S + 1.0) * per_s, kept  # its frames of at most ~2 s, not 20 s
