"""A thread that calls a function at a fixed rate on absolute deadlines.

Deadlines are ``t0 + k·period`` on ``time.monotonic``, so a late cycle does not shift the
ones after it (no drift, low period jitter); after ``resync_after`` late cycles in a row the
schedule is re-anchored instead of bursting to catch up. The wait is a
:class:`~bridge.link.stop_signal.StopSignal`'s (one lock acquire, half an ``Event.wait``'s cost), so
:meth:`PeriodicThread.stop` ends it at once. An exception in the function is handed to
``on_error`` and the loop goes on (a control loop must not die silently).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from bridge.link.stop_signal import StopSignal
from planner.errors import HitchInputError

__all__ = ["PeriodicThread", "PeriodError"]


class PeriodError(HitchInputError):
    """A period outside the range a periodic thread can keep (named in the message)."""


class PeriodicThread:
    """Runs ``fn()`` every ``period_s`` seconds in a daemon thread named ``name``."""

    def __init__(
        self,
        period_s: float,
        fn: Callable[[], None],
        *,
        name: str,
        on_error: Callable[[Exception], None] | None = None,
        resync_after: int = 3,
        clock: Callable[[], float] = time.monotonic,
    ):
        if not 1e-4 <= period_s <= 10.0:
            raise PeriodError(f"period_s must lie within [1e-4, 10] s, got {period_s!r}")
        self.period_s = float(period_s)
        self._fn = fn
        self._on_error = on_error or (lambda exc: None)
        self._resync_after = max(1, int(resync_after))
        self._clock = clock  # [s], steady (tests pass a simulated one)
        self._stop = StopSignal()  # a timed wait of one lock acquire (bridge.link.stop_signal)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.cycles = 0
        self.overruns = 0  # cycles that started after their deadline

    def start(self) -> PeriodicThread:
        self._thread.start()
        return self

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self, timeout_s: float = 0.5) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        clock = self._clock
        t_next, late = clock(), 0
        while not self._stop.is_set():
            t_next += self.period_s
            delay = t_next - clock()
            if delay > 0:
                late = 0
                if self._stop.wait(delay):
                    break
            else:
                late += 1
                self.overruns += 1
                if late >= self._resync_after:
                    t_next, late = clock(), 0
            try:
                self._fn()
            except Exception as exc:  # noqa: BLE001 — reported, the loop keeps its rate
                self._on_error(exc)
            self.cycles += 1
