"""Reference watchdog of the cylinder ECU (thesis §2.5.6 safety function).

"The program has a safety function that keeps the commands at zero unless control
messages keep arriving from the Colibri" (thesis §2.5.6).  The watchdog is fed with
the arrival time of every position reference; it is *expired* — valves must be zero —
before the first reference and as soon as the age of the last reference reaches the
timeout (``now − last ≥ timeout``, with a 1 ns tolerance for float time).  Using
``≥`` makes the valves zero exactly ``timeout`` after the last reference, so "no
reference for more than 100 ms" never passes a non-zero command.

Times in seconds of the ECU's (simulated) clock.
"""

from __future__ import annotations

import math

from planner.errors import HitchInputError

__all__ = ["WatchdogError", "Watchdog"]

#: Float-time tolerance for the expiry comparison [s].
_TIME_EPS_S = 1e-9


class WatchdogError(HitchInputError):
    """Bad watchdog configuration or time; the message names the field and the allowed range."""


class Watchdog:
    """Expires when no reference arrived for ``timeout_s`` (default 100 ms, thesis ECU)."""

    def __init__(self, timeout_s: float = 0.1) -> None:
        if isinstance(timeout_s, bool) or not isinstance(timeout_s, (int, float)) or not math.isfinite(timeout_s):
            raise WatchdogError(f"timeout_s must be a finite number of seconds, got {timeout_s!r}")
        if not 0.001 <= timeout_s <= 10.0:
            raise WatchdogError(f"timeout_s = {timeout_s} outside [0.001, 10] s")
        self.timeout_s = float(timeout_s)
        self._last: float | None = None
        self._tripped = True
        self._trips = 0

    def reset(self) -> None:
        """Forget the last reference (ECU restart): expired until the next :meth:`feed`."""
        self._last = None
        self._tripped = True

    def feed(self, now_s: float) -> None:
        """A reference arrived at ``now_s`` [s]."""
        if not math.isfinite(now_s):
            raise WatchdogError(f"now_s must be finite, got {now_s!r}")
        if self._last is not None and now_s < self._last - _TIME_EPS_S:
            raise WatchdogError(f"now_s = {now_s} is earlier than the last reference at {self._last} s")
        self._last = float(now_s)
        self._tripped = False

    def expired(self, now_s: float) -> bool:
        """True if valves must be held at zero at ``now_s`` [s]; counts each trip once."""
        if self._last is None:
            return True
        if not self._tripped and now_s - self._last >= self.timeout_s - _TIME_EPS_S:
            self._tripped = True
            self._trips += 1
        return self._tripped

    def fed_at(self, now_s: float) -> bool:
        """True if the last reference is younger than the timeout at ``now_s`` [s]: ``not expired(now_s)``
        without counting a trip (a pure reading)."""
        return self._last is not None and now_s - self._last < self.timeout_s - _TIME_EPS_S

    @property
    def last_feed_s(self) -> float | None:
        """Arrival time of the last reference [s], or None since start / reset."""
        return self._last

    @property
    def trip_count(self) -> int:
        """How often the watchdog expired after having been fed."""
        return self._trips
