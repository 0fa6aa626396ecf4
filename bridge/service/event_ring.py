"""The service's recent events, for a client that missed some: ``events/recent``.

Events are published on ``<prefix>/events`` as they happen; a subscriber that was cut off meanwhile (a router
restarted, a radio gap, a service frozen for a while) never hears those, and nothing let it ask (a fleet trial:
the abort of a goto during a router outage, ``link_lost``, were never seen; ``hitch track`` could only say
"outcome UNKNOWN"). :class:`EventRing` keeps the last :data:`KEPT_EVENTS` events the service heard, in their own
order (``seq``, numbered by the control core); ``events/recent {"after": n}`` answers those after ``n``, and says
whether some after ``n`` are no longer kept. Thread-safe; O(1) per event.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Mapping
from typing import Any

__all__ = ["EventRing", "KEPT_EVENTS", "MAX_EVENTS_PER_REPLY"]

#: events kept (a few minutes of a busy service; events are a few hundred bytes)
KEPT_EVENTS = 2000
#: the most events one reply carries (a client asks again from the last one it got)
MAX_EVENTS_PER_REPLY = 500


class EventRing:
    """The last :data:`KEPT_EVENTS` events (:meth:`take`, a listener of the service's events) and the replies of
    ``events/recent`` (:meth:`after`)."""

    def __init__(self, kept: int = KEPT_EVENTS) -> None:
        self._events: deque[dict[str, Any]] = deque(maxlen=kept)
        self._lock = threading.Lock()

    def take(self, event: Mapping[str, Any]) -> None:
        """Keep one event (a copy) as the service heard it."""
        with self._lock:
            self._events.append(dict(event))

    def after(self, seq: int, limit: int = MAX_EVENTS_PER_REPLY) -> dict[str, Any]:
        """The events numbered above ``seq`` (at most ``limit``, oldest first): ``{"events", "oldest", "latest",
        "missed", "more"}`` — ``oldest``/``latest`` the numbers kept (None: none yet), ``missed`` whether events
        after ``seq`` are no longer kept (or were never heard: numbers skipped), ``more`` whether ``limit`` cut the
        reply (ask again after the last one)."""
        with self._lock:
            kept = list(self._events)
        numbered = [e for e in kept if isinstance(e.get("seq"), int)]
        newer = [e for e in numbered if e["seq"] > seq]
        oldest = numbered[0]["seq"] if numbered else None
        latest = numbered[-1]["seq"] if numbered else None
        answered = [seq] + [e["seq"] for e in newer[:limit]]
        # a number skipped anywhere up to the last answered: not kept, or never heard (a review: only the first
        # was compared, and a gap after it was reported as nothing missed)
        missed = any(b - a > 1 for a, b in zip(answered, answered[1:], strict=False))
        return {
            "events": newer[:limit],
            "oldest": oldest,
            "latest": latest,
            "missed": missed,
            "more": len(newer) > limit,
        }
