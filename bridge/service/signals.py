"""SIGINT / SIGTERM as a flag the main loop polls (``hitch serve``, ``hitch router``).

A Python signal handler runs in the main thread between two of its bytecodes — possibly while the
main thread is inside ``threading.Event.wait`` holding that event's own (non-reentrant) lock. A
handler that calls ``Event.set`` then waits for the lock its own thread holds: ``hitch serve`` hung
there for good after a SIGTERM (seen: the main thread's stack four handlers deep in
``Condition.__enter__``). The handler here only sets a flag; :meth:`StopSignals.wait` sleeps in short
steps (``time.sleep`` takes no lock) and looks at it.
"""

from __future__ import annotations

import signal
import time
from types import TracebackType
from typing import Any

__all__ = ["POLL_S", "StopSignals"]

#: how often :meth:`StopSignals.wait` looks at the flag [s] (the most a stop waits for the loop)
POLL_S = 0.05


class StopSignals:
    """``with StopSignals() as stop: while not stop.wait(0.5): ...`` — SIGINT and SIGTERM set
    :attr:`received` (main thread only, as Python's signal handlers); the old handlers come back on exit."""

    def __init__(self) -> None:
        self.received = False
        self._old: dict[int, Any] = {}

    def _on_signal(self, signum: int, frame: object) -> None:
        self.received = True  # nothing else: no lock, no I/O

    def __enter__(self) -> StopSignals:
        self._old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)

    def wait(self, timeout_s: float) -> bool:
        """Up to ``timeout_s`` [s] for a stop signal; whether one came (at most :data:`POLL_S` late)."""
        end = time.monotonic() + timeout_s
        while not self.received:
            left = end - time.monotonic()
            if left <= 0:
                return False
            time.sleep(min(left, POLL_S))
        return True
