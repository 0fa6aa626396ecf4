"""A one-shot stop flag whose timed wait costs one lock acquire.

The real-time runners and the periodic control thread sleep between their deadlines in a wait
that a stop must end at once. ``threading.Event.wait(timeout)`` builds a ``Condition`` waiter
(a new lock, two acquires, a release) for every wait; a thread that wakes at 100 Hz and does
nothing else costs 1.04 % of a core through it, 0.82 % through a single
``Lock.acquire(timeout=...)`` and 0.69 % in ``time.sleep`` (medians, side by side:
``bench/wait_cost_bench.py``, 2026-12-05; 1.28 / 0.71 % in an earlier run). :class:`StopSignal`
is that lock: held from the start, released once by :meth:`StopSignal.set`; a waiter that gets
it releases it again, so every waiter, present and future, returns at once.
"""

from __future__ import annotations

import threading

__all__ = ["StopSignal"]


class StopSignal:
    """``set()`` once, ``is_set()``, ``wait(timeout_s)`` — the part of ``threading.Event`` a stop needs.

    Not resettable (a stopped runner is not restarted).
    """

    __slots__ = ("_flag", "_gate", "_set_lock")

    def __init__(self) -> None:
        self._flag = False
        self._gate = threading.Lock()
        self._gate.acquire()  # held until set(): a waiter blocks on it
        self._set_lock = threading.Lock()

    def is_set(self) -> bool:
        return self._flag

    def set(self) -> None:
        """Stop: every wait, present and future, returns True. Idempotent, from any thread."""
        with self._set_lock:
            if not self._flag:
                self._flag = True
                self._gate.release()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until :meth:`set` or ``timeout_s`` seconds (None: no limit; ≤ 0: do not block).
        Returns True when set, as ``Event.wait``."""
        if self._flag:
            return True
        if timeout_s is None:
            got = self._gate.acquire()
        elif timeout_s > 0.0:
            got = self._gate.acquire(True, timeout_s)
        else:
            got = self._gate.acquire(False)
        if got:  # set: hand the gate on to the next waiter
            self._gate.release()
            return True
        return self._flag
