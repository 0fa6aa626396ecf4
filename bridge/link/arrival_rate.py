"""Frames of one source arriving faster than their sender sends them: a second node sending as its address.

A leaky bucket over the arrival times of one source's frames (bus stamps when the link trusts them, else read
times). ``e`` counts the frames ahead of the rate the source may arrive at, :data:`RATE_FACTOR` × its sender's
rate ``1/T``; it rests at ``−allowance`` and each frame moves it as

    e ← max(e − F·Δt/T, −allowance) + 1,        allowance = (F − 1)·W/T + 3 frames,

so frames within ``allowance`` of that rate are taken and a source arriving faster fills ``e`` above 0: every
frame is refused then (readings of two senders may lie within the jump allowance of each other: a recheck saw
a spoof 8 counts off taken as the pose). ``e`` is capped at ``allowance``: once the rate is normal again the
frames are taken within ``allowance / ((F − 1)/T)`` (0.19 s at 100 Hz).

Gaps, on read times only: a gap of Δt > :data:`GAP_PERIODS` · T owes ``Δt/T − 1`` frames; its backlog may follow
at once (frames a stalled reader finds waiting all carry the same read time, a review: stalls of 0.85–1.5 s were
then refused as "two nodes" for 2 s more), so ``e`` goes that far below its rest; that credit expires at the rate
the bucket drains (F/T). The first frame read owes :data:`START_BACKLOG_S` of frames (those waiting when the
reader started). Bus stamps keep a backlog's own spacing: a stamped gap is frames that never came and lends
nothing (a review: credit lent by a silent ECU's gap let a spoof beside the returning ECU pass for up to 2.2 s).
Clock steps: a bus stamp that went back,
or forward further than the read times (:data:`STAMP_SLACK_S`), is the bus's wall clock stepping (NTP, a GNSS
time fix): that frame's Δt is the read times' (a review: a 5 s step back refused 522 genuine frames as "two
nodes" for 5.2 s and grew the arrival list without bound).

Pure: no clock, no I/O; bounded memory.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

__all__ = [
    "ArrivalRate",
    "RATE_FACTOR",
    "RATE_WINDOW_S",
    "GAP_PERIODS",
    "MAX_OWED_S",
    "START_BACKLOG_S",
    "STAMP_SLACK_S",
]

#: the fastest a source's frames may arrive, as a multiple of its sender's rate
RATE_FACTOR = 1.8
#: the window [s] whose excess frames (at RATE_FACTOR) plus 3 a burst may bring at once: 15 frames at 100 Hz (a
#: 300/s spoof beside a 100 Hz ECU is refused within about 0.07 s, a 200/s one within 0.12 s)
RATE_WINDOW_S = 0.15
#: a time between two frames longer than this many periods is a gap whose frames may follow as a backlog
GAP_PERIODS = 2.0
#: the longest gap whose backlog is credited [s] (a longer stall's remaining backlog counts as a burst)
MAX_OWED_S = 10.0
#: the frames the first one read may bring with it, in seconds of its sender's frames (read times only) [s]
START_BACKLOG_S = 2.0
#: how far two bus stamps may lie further apart than their read times before the stamps are taken for a step
#: of the bus's wall clock [s] (frames read together at a deadline lie a few periods apart)
STAMP_SLACK_S = 1.0
#: arrival times kept to say the rate a refusal saw (frames)
_RATE_SAMPLES = 64


@dataclass
class ArrivalRate:
    """The arrival check of one source whose sender sends every ``period_s`` [s] (:meth:`arrive`)."""

    period_s: float
    excess: float = field(init=False)
    last: tuple[float, float] | None = field(default=None, init=False)  # (time used, read time) of the last frame
    times: deque[float] = field(default_factory=lambda: deque(maxlen=_RATE_SAMPLES), init=False)

    def __post_init__(self) -> None:
        self.excess = -self.allowance

    @property
    def allowance(self) -> float:
        """Frames a burst may bring beyond :data:`RATE_FACTOR` × the sender's rate."""
        return (RATE_FACTOR - 1.0) * RATE_WINDOW_S / self.period_s + 3.0

    def arrive(self, read_s: float, stamp_s: float | None = None) -> bool:
        """A frame read at ``read_s`` [s], stamped ``stamp_s`` by a trusted bus clock (None: unstamped): whether
        it arrived too fast to be taken (the bucket is above its limit)."""
        t = read_s if stamp_s is None else stamp_s
        base, rate = -self.allowance, RATE_FACTOR / self.period_s
        if self.last is None:
            dt = START_BACKLOG_S if stamp_s is None else 0.0  # read times: frames waiting at the start may follow
        else:
            dt = t - self.last[0]
            read_dt = max(read_s - self.last[1], 0.0)
            if stamp_s is not None and not 0.0 <= dt <= read_dt + STAMP_SLACK_S:
                dt = read_dt  # the bus's wall clock stepped: the read times tell the time between
                self.times.clear()
            dt = max(dt, 0.0)
        e = self.excess
        e = min(base, e + rate * dt) if e < base else max(e - rate * dt, base)  # credit expires; excess drains
        if stamp_s is None and dt > GAP_PERIODS * self.period_s:
            e = min(e, base) - (min(dt, MAX_OWED_S) / self.period_s - 1.0)  # a gap: its backlog may follow
        self.excess = min(e + 1.0, self.allowance)
        self.last = (t, read_s)
        self.times.append(t)
        return self.excess > 0.0

    def rate_hz(self) -> float:
        """The rate the last frames arrived at [1/s] (0 with fewer than two, ``inf`` when all at one time)."""
        if len(self.times) < 2:
            return 0.0
        span = self.times[-1] - self.times[0]
        return (len(self.times) - 1) / span if span > 0.0 else float("inf")

    def arrival_words(self) -> str:
        """How the last frames arrived, for a refusal: "400 times a second", or "32 frames at one time"."""
        rate = self.rate_hz()
        if rate == float("inf"):
            n = len(self.times)
            return f"{n}{' or more' if n == self.times.maxlen else ''} frames at one time"
        return f"{rate:.0f} times a second"
