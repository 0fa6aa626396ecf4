"""ISO 11783-7 heartbeat (PGN 61668): a pure sender and a pure monitor.

Sender (ISO 11783-7 B.33.3.2): every 100 ms one frame whose sequence number is
251 once after initialisation, then 0, 1, ..., 250, 0, ...; 254 signals a sender
error and 255 a graceful shutdown.

Monitor (B.33.3.3-4), per sender: the sequence must advance by one (after 250 or
251 comes 0); up to two lost heartbeats (an advance of 2 or 3) are tolerated, a
repeat or a larger jump is a sequence error; 252-253 are ignored; 251 means the
sender restarted; more than 300 ms without a heartbeat is a communication error.
After any error, eight consecutive correct heartbeats (or a restart, 251) return
the monitor to operational.

A counter that errs against the last heartbeat but continues one heard before it
(10, 200, 11, 201, … or 0, 0, 1, 1, …) is two counters interleaved: two nodes
sending with the one source address (a second simulated ECU on the bus). After
two such heartbeats (before the monitor is operational again) the status says so
(:attr:`HeartbeatStatus.interleaved`, :meth:`HeartbeatStatus.sequence_error_hint`);
a single jump, or one repeat, is not taken for it.

Neither class owns a thread or a clock: both are driven by ``now_s``.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import Enum

import can

from bridge.isobus.codec import CodecError, Heartbeat, decode_frame, encode
from bridge.isobus.j1939 import PGN_HEARTBEAT, PLANNER_ADDRESS, J1939Error, decode_id
from planner.errors import HitchInputError

__all__ = [
    "HEARTBEAT_PERIOD_S",
    "HeartbeatError",
    "HEARTBEAT_TIMEOUT_S",
    "HeartbeatMonitor",
    "HeartbeatSender",
    "HeartbeatState",
    "HeartbeatStatus",
    "INITIAL_SEQUENCE",
    "RECOVERY_COUNT",
    "SEQUENCE_ERROR",
    "SEQUENCE_MODULUS",
    "SEQUENCE_SHUTDOWN",
]

HEARTBEAT_PERIOD_S = 0.1
"""Transmission period, s."""
HEARTBEAT_TIMEOUT_S = 0.3
"""Silence after which the monitor reports a communication error, s."""
INITIAL_SEQUENCE = 251
"""Sequence number sent once after initialisation."""
SEQUENCE_ERROR = 254
"""Sequence number signalling an error in the sender."""
SEQUENCE_SHUTDOWN = 255
"""Sequence number signalling a graceful shutdown."""
SEQUENCE_MODULUS = 251
"""Normal sequence numbers run 0..250."""
RECOVERY_COUNT = 8
"""Consecutive correct heartbeats needed to leave an error state."""
_MAX_ADVANCE = 3  # advance 2 or 3 = one or two heartbeats lost, tolerated
_INTERLEAVE_WINDOW = 8  # heartbeats over which interleaved counters are looked for
_INTERLEAVE_EVIDENCE = 2  # heartbeats continuing an earlier counter (not the last) within the window: two senders
_TIME_EPS_S = 1e-6  # a gap of exactly the timeout (within float noise) is still on time


class HeartbeatError(HitchInputError):
    """A heartbeat period, timeout or sequence number outside its allowed range."""


class HeartbeatSender:
    """Periodic heartbeat frames from one source address.

    Args:
        source: our source address.
        period_s: period, s (ISO 11783-7: 0.1).
    """

    def __init__(self, source: int = PLANNER_ADDRESS, *, period_s: float = HEARTBEAT_PERIOD_S) -> None:
        if not period_s > 0:
            raise HeartbeatError(f"period_s must be > 0 s, got {period_s!r}")
        self._source = source
        self._period_s = float(period_s)
        self._sequence: int | None = None  # last sent counter value, None before start
        self._anchor_s = 0.0  # frame k is due at anchor + k * period (no drift)
        self._count = 0
        self._fault = False

    @property
    def started(self) -> bool:
        """True after :meth:`start`."""
        return self._sequence is not None

    @property
    def fault(self) -> bool:
        """While True the frames carry the error value 254."""
        return self._fault

    @fault.setter
    def fault(self, value: bool) -> None:
        self._fault = bool(value)

    def start(self, now_s: float) -> list[can.Message]:
        """(Re)initialise: send 251 now, the counter follows every period."""
        self._sequence = INITIAL_SEQUENCE
        self._anchor_s, self._count = now_s, 1
        return [self._frame(INITIAL_SEQUENCE)]

    def poll(self, now_s: float) -> list[can.Message]:
        """Return the heartbeat due at ``now_s`` (at most one; no catch-up bursts)."""
        if self._sequence is None:
            return []
        due_s = self._anchor_s + self._count * self._period_s
        if now_s < due_s - _TIME_EPS_S:
            return []
        if now_s - due_s >= self._period_s - _TIME_EPS_S:  # a period or more late: re-phase
            self._anchor_s, self._count = now_s, 1
        else:
            self._count += 1
        if self._fault:
            return [self._frame(SEQUENCE_ERROR)]
        self._sequence = 0 if self._sequence >= SEQUENCE_MODULUS - 1 else self._sequence + 1
        return [self._frame(self._sequence)]

    def shutdown(self) -> list[can.Message]:
        """Graceful disconnection: one frame with 255; the sender stops."""
        self._sequence = None
        return [self._frame(SEQUENCE_SHUTDOWN)]

    def _frame(self, sequence: int) -> can.Message:
        return encode(Heartbeat(sequence), source=self._source)


class HeartbeatState(Enum):
    """What the monitor concludes about one sender."""

    WAITING = "waiting"  # nothing received yet
    OPERATIONAL = "operational"
    SEQUENCE_ERROR = "sequence error"  # repeat or jump of the counter
    SENDER_ERROR = "sender error"  # the sender sent 254
    SHUTDOWN = "shutdown"  # the sender sent 255
    TIMEOUT = "timeout"  # more than the timeout without a heartbeat


@dataclass(frozen=True)
class HeartbeatStatus:
    """A snapshot of a :class:`HeartbeatMonitor`.

    Attributes:
        state: current conclusion.
        last_sequence: last sequence number received, ``None`` before the first.
        age_s: time since the last heartbeat, s (``None`` before the first).
        restarts: how many times the sender restarted (251 after the first frame).
        sequence_errors: sequence errors seen.
        timeouts: silences longer than the timeout seen.
        last_gap_s: the gap between two heartbeats that last counted as a silence, s (``None``: none yet);
            a timeout state with a young ``age_s`` is this gap, not yet recovered from.
    """

    state: HeartbeatState
    last_sequence: int | None
    age_s: float | None
    restarts: int
    sequence_errors: int
    timeouts: int
    last_gap_s: float | None = None
    interleaved: bool = False
    source: int | None = None

    @property
    def healthy(self) -> bool:
        """True only when operational."""
        return self.state is HeartbeatState.OPERATIONAL

    def sequence_error_hint(self) -> str | None:
        """The likely cause of a sequence error whose counter runs as two interleaved sequences (``interleaved``):
        two nodes sending heartbeats with one source address. None otherwise (a single jump or repeat, another
        state): a reason says it only when it fits."""
        if self.state is not HeartbeatState.SEQUENCE_ERROR or not self.interleaved:
            return None
        who = "" if self.source is None else f" {self.source} = 0x{self.source:02X}"
        return (
            "the counter interleaves two sequences, possibly two nodes sending with source address"
            f"{who} (e.g. a second hitch ecu-sim on the bus)"
        )


class HeartbeatMonitor:
    """Checks the heartbeat of one sender.

    Args:
        source: the sender's source address.
        timeout_s: silence that counts as a communication error, s (0.3).
    """

    def __init__(self, source: int, *, timeout_s: float = HEARTBEAT_TIMEOUT_S) -> None:
        if not timeout_s > 0:
            raise HeartbeatError(f"timeout_s must be > 0 s, got {timeout_s!r}")
        self._source = source
        self._timeout_s = float(timeout_s)
        self._state = HeartbeatState.WAITING
        self._last: int | None = None
        self._counter: int | None = None  # last value in 0..251, for the advance check
        self._last_rx_s: float | None = None
        self._last_stamp_s: float | None = None  # the last heartbeat's own timestamp (None: it had none)
        self._good_run = 0
        self._restarts = 0
        self._sequence_errors = 0
        self._timeouts = 0
        self._last_gap_s: float | None = None
        self._recent: deque[int] = deque(maxlen=_INTERLEAVE_WINDOW)  # the last counters (0..251) received
        self._evidence: deque[bool] = deque(maxlen=_INTERLEAVE_WINDOW)  # per heartbeat: continued an older one

    def handle(self, frame: can.Message, now_s: float) -> bool:
        """Process a received frame; True if it was a heartbeat from our sender."""
        if not frame.is_extended_id:
            return False
        try:
            ident = decode_id(frame.arbitration_id)
            if ident.pgn != PGN_HEARTBEAT or ident.source_address != self._source:
                return False
            payload = decode_frame(frame).payload
        except (CodecError, J1939Error):
            return False  # reserved 252-253 and malformed heartbeats are ignored
        if not isinstance(payload, Heartbeat):
            return False
        sequence = payload.sequence
        self.handle_sequence(sequence, now_s)
        return True

    def handle_sequence(self, sequence: int, now_s: float, *, stamp_s: float | None = None) -> None:
        """Process one received sequence number at time ``now_s``.

        ``stamp_s``: the frame's own timestamp on the bus (s, any clock whose differences are seconds),
        if the caller trusts it. The gap to the previous heartbeat is then the smaller of the read times'
        and the timestamps' difference: heartbeats that waited in the bus while the reader stalled keep
        their real spacing (a stall of the reader is not a silence of the sender), and a clock stepped
        forward cannot make a heartbeat late. Silence *now* (:meth:`status`) is always judged by read time.
        """
        if isinstance(sequence, bool) or not isinstance(sequence, int) or not (0 <= sequence <= 255):
            raise HeartbeatError(f"sequence must be an integer in 0..255, got {sequence!r}")
        if sequence in (252, 253):
            return
        if self._last_rx_s is not None:
            gap = now_s - self._last_rx_s
            if stamp_s is not None and self._last_stamp_s is not None:
                gap = min(gap, max(0.0, stamp_s - self._last_stamp_s))
            if gap > self._timeout_s + _TIME_EPS_S:
                self._timeouts += 1
                self._last_gap_s = gap
                self._enter(HeartbeatState.TIMEOUT)
        self._last_rx_s, self._last_stamp_s = now_s, stamp_s
        first, self._last = self._last is None, sequence
        if sequence == SEQUENCE_ERROR:
            self._enter(HeartbeatState.SENDER_ERROR)
        elif sequence == SEQUENCE_SHUTDOWN:
            self._counter = None
            self._enter(HeartbeatState.SHUTDOWN)
        elif sequence == INITIAL_SEQUENCE:
            self._restarts += 0 if first else 1
            self._counter = INITIAL_SEQUENCE
            self._state, self._good_run = HeartbeatState.OPERATIONAL, RECOVERY_COUNT
        elif self._counter is None:
            if first:  # joined a running sender: synchronise
                self._state, self._good_run = HeartbeatState.OPERATIONAL, RECOVERY_COUNT
            else:  # counting resumed after 255 without the initial 251
                self._sequence_error()
            self._counter = sequence
        else:
            advance = _advance(self._counter, sequence)
            if advance == 0 or advance > _MAX_ADVANCE:  # repeat or jump
                self._evidence.append(self._continues_earlier(sequence))
                self._sequence_error()
            elif advance == 1:
                self._good_run += 1
                if self._good_run >= RECOVERY_COUNT:
                    self._state = HeartbeatState.OPERATIONAL
            self._counter = sequence
        if sequence <= INITIAL_SEQUENCE:
            self._recent.append(sequence)
        if self._state is HeartbeatState.OPERATIONAL:
            self._evidence.clear()

    def _continues_earlier(self, sequence: int) -> bool:
        """Whether ``sequence`` (an error against the last counter) advances by 1..3 from the counter heard just
        before the last: the mark of a second sender interleaving its own count."""
        if len(self._recent) < 2:
            return False
        return 1 <= _advance(self._recent[-2], sequence) <= _MAX_ADVANCE

    def status(self, now_s: float) -> HeartbeatStatus:
        """The monitor's conclusion at ``now_s``."""
        state = self._state
        age = None if self._last_rx_s is None else now_s - self._last_rx_s
        if age is not None and age > self._timeout_s + _TIME_EPS_S:
            state = HeartbeatState.TIMEOUT
        return HeartbeatStatus(
            state,
            self._last,
            age,
            self._restarts,
            self._sequence_errors,
            self._timeouts,
            self._last_gap_s,
            interleaved=sum(self._evidence) >= _INTERLEAVE_EVIDENCE,
            source=self._source,
        )

    def healthy(self, now_s: float) -> bool:
        """True when the sender is operational and not silent."""
        return self.status(now_s).healthy

    def _sequence_error(self) -> None:
        self._sequence_errors += 1
        self._enter(HeartbeatState.SEQUENCE_ERROR)

    def _enter(self, state: HeartbeatState) -> None:
        self._state = state
        self._good_run = 0


def _advance(previous: int, sequence: int) -> int:
    """How far ``sequence`` advances the counter from ``previous`` (251, the initial value, counts as -1)."""
    base = -1 if previous == INITIAL_SEQUENCE else previous
    return (sequence - base) % SEQUENCE_MODULUS
