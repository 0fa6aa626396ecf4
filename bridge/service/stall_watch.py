"""When a request handled now may have arrived: the service's own stalls make arrival times late.

A request is stamped with its arrival (``time.monotonic()``) when the service's Python takes it from Zenoh; a
motion request's ``deadline_ms`` counts from then, and a stop refuses what arrived before it (or within
:data:`~bridge.service.motion.controller.STOP_GRACE_S` after it). A service that does not run for a while —
frozen (SIGSTOP), swapped out, starved — takes everything sent meanwhile only when it runs again, and stamped
then it looks sent then. A fleet trial: the service frozen 1.5 s, a goto sent 0.3 s into it, a stop 1.0 s later
answered by the control core in its own process (not frozen) — and after the thaw the goto started, 1.2 s
after it was sent and after a stop its client had been told succeeded.

:class:`StallWatch` ticks on a thread of its own every :data:`TICK_S`; a tick more than :data:`STALL_S` after the
one before it ends a stall, which began at that tick before. What this process takes during a stall (before its
tick has noticed it: more than ``STALL_S`` since the last tick) or within :data:`DRAIN_S` after the stall's
end may have arrived any time since the stall began (what was sent meanwhile waits in the rings and is taken
after the thaw, in whatever order the threads then run): :meth:`StallWatch.arrival` gives the stall's start,
the earliest it may have arrived (a stop in between refuses it; its deadline counts from then). A stall of at
most ``STALL_S`` is covered by the stop's own grace (``STALL_S`` ≤ ``STOP_GRACE_S``). Under CPU load the ticks
are themselves late by tens of ms: requests may then be stamped up to that much early, and a request truly sent
within ``DRAIN_S`` after a stall counts from the stall's start. Both can only refuse a request (``busy``: send
it again), never run one late.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

__all__ = ["CHAIN_MAX_S", "DRAIN_S", "STALL_S", "TICK_S", "StallWatch"]

#: the watch's period [s]
TICK_S = 0.02
#: a gap since the last tick longer than this is a stall [s]; at most the stop's grace (0.1 s)
STALL_S = 0.1
#: for this long after a stall's end what is taken counts as arrived at the stall's start [s]: what was sent during
#: it is taken after the thaw, and the threads that take it may run after the tick that notices the stall
DRAIN_S = 0.5
#: a stall beginning within DRAIN_S after the last one continues it, as long as that one began at most this long
#: before [s] (a request still untaken after it is stamped later than it was sent: the limit of this watch)
CHAIN_MAX_S = 2.0


class StallWatch:
    """See the module docstring; ``clock``: the time source (``time.monotonic``), for tests."""

    def __init__(self, *, clock: Callable[[], float] = time.monotonic, tick_s: float = TICK_S) -> None:
        self._clock = clock
        self._tick_s = tick_s
        self._last = clock()
        #: the last stall (start, end) [s on the clock]; None: none yet
        self._stall: tuple[float, float] | None = None
        self._closed = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> StallWatch:
        """Tick on a daemon thread (``hitch-stall-watch``) until :meth:`close`."""
        if self._thread is None:
            self._last = self._clock()  # from now: the time since it was made is no stall (a review)
            self._thread = threading.Thread(target=self._run, name="hitch-stall-watch", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        self._closed.set()

    def tick(self) -> None:
        """This process runs now (the thread's tick); a gap of more than :data:`STALL_S` since the last was a
        stall."""
        now = self._clock()
        if now - self._last > STALL_S:
            # a stall that begins within DRAIN_S after the last one ended continues it: what was sent during the
            # first may still wait to be taken (a review: stamped with the second's start, after a stop in the
            # first, a request sent before that stop would have run)
            # — up to CHAIN_MAX_S back: stalls every half second for long (a loaded machine) would otherwise push
            # every stamp back without end and refuse every motion request as late (a review)
            prev = self._stall
            chained = prev is not None and self._last - prev[1] <= DRAIN_S and self._last - prev[0] <= CHAIN_MAX_S
            start = prev[0] if chained and prev is not None else self._last
            self._stall = (start, now)
        self._last = now

    def arrival(self, now: float | None = None) -> float:
        """The earliest time a request taken ``now`` (default the clock) may have arrived: ``now``; during a
        stall its tick has not noticed yet (more than :data:`STALL_S` since the last tick) that tick's time;
        within :data:`DRAIN_S` after a stall's end the stall's start."""
        t = self._clock() if now is None else float(now)
        last, stall = self._last, self._stall
        if t - last > STALL_S:
            return last
        if stall is not None and t - stall[1] <= DRAIN_S:
            return stall[0]
        return t

    def _run(self) -> None:
        while not self._closed.wait(self._tick_s):
            self.tick()
