"""The arrival-rate check of one source (bridge.link.arrival_rate): frames faster than their sender sends them.

Truth: the bucket's closed forms (a spoof of rate s beside a sender of period T is refused after
``(allowance − 1) / (1/T + s − F/T)`` s; frames are taken again ``allowance / ((F − 1)/T)`` s after it stops),
and genuine traffic — jittered, batched, stalled with its backlog read at once, across steps of the bus clock —
never refused.
"""

from __future__ import annotations

import numpy as np
import pytest

from bridge.link.arrival_rate import RATE_FACTOR, ArrivalRate

T = 0.01  # a 100 Hz sender


def _first_refused(rate: ArrivalRate, times, stamps=None) -> float | None:
    for k, t in enumerate(times):
        if rate.arrive(float(t), None if stamps is None else float(stamps[k])):
            return float(t)
    return None


def test_a_spoof_beside_the_sender_is_refused_when_the_bucket_fills_as_its_closed_form_says():
    for spoof_hz in (100.0, 200.0, 300.0):
        rate = ArrivalRate(T)
        own = np.arange(0.0, 2.0, T)
        spoof = np.arange(0.5 * T / 1.0, 2.0, 1.0 / spoof_hz) + 1e-4
        times = np.sort(np.concatenate([own, spoof]))
        first = _first_refused(rate, times, times)
        total_hz = 1.0 / T + spoof_hz
        growth = total_hz - RATE_FACTOR / T  # frames a second above what drains
        assert first is not None, spoof_hz
        expected = (rate.allowance - 1.0) / growth
        assert abs(first - expected) <= T, (spoof_hz, first, expected)  # within one of the sender's periods
    assert rate.allowance == pytest.approx((RATE_FACTOR - 1.0) * 0.15 / T + 3.0)


def test_after_a_spoof_stops_the_senders_frames_are_taken_within_the_allowance_over_the_drain():
    rate = ArrivalRate(T)
    spoofed = np.sort(np.concatenate([np.arange(0.0, 1.0, T), np.arange(0.0, 1.0, 1 / 300) + 1e-4]))
    refused = [rate.arrive(float(t), float(t)) for t in spoofed]
    assert all(r for t, r in zip(spoofed, refused, strict=True) if t > 0.2)  # refused throughout
    after = np.arange(1.0, 2.0, T)
    refused = [t for t in after if rate.arrive(float(t), float(t))]
    recover = rate.allowance / ((RATE_FACTOR - 1.0) / T)  # the cap drains at (F - 1)/T
    assert refused and max(refused) - 1.0 <= recover + T, (max(refused), recover)


@pytest.mark.parametrize("stall_s", [0.5, 0.85, 0.9, 1.5, 5.0])
def test_a_stalled_readers_backlog_read_at_once_is_never_refused(stall_s):
    """A review: stalls of 0.85–1.5 s (read times, the backlog read at once) were refused as "two nodes" for 2 s
    after the backlog was read."""
    rate = ArrivalRate(T)
    sent = np.arange(0.0, 3.0 + stall_s + 3.0, T)
    read = np.where((sent >= 1.0) & (sent < 1.0 + stall_s), 1.0 + stall_s, sent)
    assert _first_refused(rate, read) is None


@pytest.mark.parametrize("step_s", [-5.0, -0.5, 3600.0])
def test_a_step_of_the_bus_clock_refuses_no_genuine_frame_and_keeps_memory_bounded(step_s):
    """A review: the bus clock (wall-clock stamps) stepped back 5 s; 522 genuine frames were refused as "two
    nodes" for 5.2 s and the arrival list grew with every frame."""
    rate = ArrivalRate(T)
    read = np.arange(0.0, 10.0, T)
    stamps = 1000.0 + read + np.where(read >= 1.0, step_s, 0.0)
    assert _first_refused(rate, read, stamps) is None
    assert len(rate.times) <= 64


def test_jittered_and_batched_genuine_traffic_is_never_refused():
    rng = np.random.default_rng(11)
    sent = np.arange(0.0, 60.0, T)
    stamps = sent + rng.uniform(-0.003, 0.003, sent.size)  # the sender's jitter
    read = np.ceil(sent / 0.04) * 0.04  # a reader that takes the bus every 40 ms
    assert _first_refused(ArrivalRate(T), read, np.sort(stamps)) is None
    assert _first_refused(ArrivalRate(T), read) is None


def test_a_gap_whose_frames_never_come_lends_its_credit_only_briefly():
    """The sender paused 2 s (no backlog): its 199 frames of credit expire at F/T plus the sender's own frames,
    within 2 s / (F + 1) = 0.71 s; a spoof beginning 0.75 s after the pause is refused as soon as without it."""
    own = np.concatenate([np.arange(0.0, 1.0, T), np.arange(3.0, 5.0, T)])
    spoof = np.arange(3.75, 5.0, 1 / 300) + 1e-4
    times = np.sort(np.concatenate([own, spoof]))
    first = _first_refused(ArrivalRate(T), times, times)
    plain = np.sort(np.concatenate([np.arange(0.0, 5.0, T), spoof]))
    assert first is not None and abs(first - _first_refused(ArrivalRate(T), plain, plain)) < 1e-9


@pytest.mark.parametrize("silent_s", [2.0, 10.0])
def test_a_stamped_gap_lends_no_credit_to_a_spoof_beside_the_returning_sender(silent_s):
    """A review: a silent ECU's gap (stamped: its frames never come) lent up to 999 frames of credit, and a 300/s
    spoof beside the returning ECU passed for up to 1.8 s. Stamps keep a backlog's spacing: no credit there."""
    back = 1.0 + silent_s
    own = np.concatenate([np.arange(0.0, 1.0, T), np.arange(back, back + 2.0, T)])
    spoof = np.arange(back, back + 2.0, 1 / 300) + 1e-4
    times = np.sort(np.concatenate([own, spoof]))
    first = _first_refused(ArrivalRate(T), times, times)
    assert first is not None and first - back <= (ArrivalRate(T).allowance - 1.0) / (400 - RATE_FACTOR / T) + T


@pytest.mark.parametrize("waiting", [30, 150])
def test_frames_waiting_when_the_reader_starts_are_taken_and_a_burst_is_named_as_one(waiting):
    """A review: 30 frames waiting at the link's first read (read times) were refused as "two nodes", saying
    "arrives 0 times a second"."""
    rate = ArrivalRate(T)
    read = np.concatenate([np.full(waiting, 0.3), 0.3 + T * np.arange(1, 300)])
    assert _first_refused(rate, read) is None
    burst = ArrivalRate(T)
    assert any([burst.arrive(5.0) for _ in range(300)])  # 300 at once, past the start's 2 s of frames
    assert burst.arrival_words() == "64 or more frames at one time"  # the last 64 are kept
