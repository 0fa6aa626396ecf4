"""The motion controller's outbox: events numbered and delivered in order, off the control thread.

Every event gets its ``seq`` (monotonic per service, from 1) when it is *put* — the controller puts
them under its lock, so the numbering is the order in which things happened — and is delivered
to ``on_event`` in that order, never two at a time. State messages take the same way (newest
wins: at most ``max_states`` wait, older ones are dropped and counted), so JSON serialisation,
Zenoh puts and listeners (the web terminal) run on the outbox's own thread, not in the control
cycle.

Two ways to deliver:

* threaded (:meth:`Outbox.start`, the service): a daemon thread ``hitch-outbox`` drains the
  queue; :meth:`Outbox.flush` only wakes it;
* synchronous (tests that drive ``cycle()`` by hand): :meth:`Outbox.flush` delivers everything
  queued, in order, in the calling thread. A flush from inside a delivery (a listener that
  calls the controller) returns at once: the delivery already running delivers the rest after
  it, so the order holds.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

__all__ = ["Outbox", "ToJson"]


class ToJson(Protocol):
    """A value sent as JSON (e.g. :class:`bridge.service.state_message.StateMessage`)."""

    def to_json(self) -> dict[str, Any]: ...


class Outbox:
    """Ordered delivery of events (numbered) and state messages (newest wins)."""

    def __init__(
        self,
        on_event: Callable[[dict[str, Any]], None],
        on_state: Callable[[dict[str, Any]], None],
        *,
        max_states: int = 4,
        max_events: int = 10_000,
    ):
        self._on_event, self._on_state = on_event, on_state
        self._mu = threading.Lock()
        self._items: deque[tuple[bool, dict[str, Any] | ToJson]] = deque()  # (is_event, payload)
        self._states_waiting = self._events_waiting = 0
        self._max_states, self._max_events = max(1, int(max_states)), max(1, int(max_events))
        self._seq = 0
        self._busy = False
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.dropped_states = 0
        self.dropped_events = 0

    @property
    def seq(self) -> int:
        """The last event number given out."""
        return self._seq

    @property
    def threaded(self) -> bool:
        return self._thread is not None

    def put_event(self, event: dict[str, Any]) -> dict[str, Any]:
        """Number ``event`` (``seq``) and stamp it (``t``: Unix time [s], the same base in every event); a
        ``t`` the event brings (the controller's clock: maneuver steps, work fallbacks) becomes its ``clock``
        [s], the base of the state's ``clock``. Queues it; returns it numbered."""
        with self._mu:
            self._seq += 1
            e = {"seq": self._seq, **event}
            if "t" in event and "clock" not in event:
                e["clock"] = event["t"]
            e["t"] = time.time()
            e["seq"] = self._seq
            if self._events_waiting >= self._max_events:  # a listener that hangs: keep the newest
                for i, (ev, _) in enumerate(self._items):
                    if ev:
                        del self._items[i]
                        self._events_waiting -= 1
                        self.dropped_events += 1
                        break
            self._items.append((True, e))
            self._events_waiting += 1
        return e

    def put_state(self, msg: dict[str, Any] | ToJson) -> None:
        """Queue a state message (a dict, or a value whose ``to_json()`` is called on delivery:
        serialised off the control thread); when ``max_states`` already wait the oldest is dropped."""
        with self._mu:
            if self._states_waiting >= self._max_states:
                for i, (ev, _) in enumerate(self._items):
                    if not ev:
                        del self._items[i]
                        self._states_waiting -= 1
                        self.dropped_states += 1
                        break
            self._items.append((False, msg))
            self._states_waiting += 1

    def flush(self) -> None:
        """Deliver what is queued (synchronous) or wake the outbox thread (threaded)."""
        if self._thread is not None:
            if self._items:  # nothing queued: no wake-up (a cycle that queued nothing costs the outbox nothing)
                self._wake.set()
            return
        self._drain()

    def _drain(self) -> None:
        with self._mu:
            if self._busy:  # someone is delivering (maybe this thread, re-entered): it delivers ours too
                return
            self._busy = True
        while True:
            with self._mu:
                if not self._items:
                    self._busy = False
                    return
                is_event, payload = self._items.popleft()
                if is_event:
                    self._events_waiting -= 1
                else:
                    self._states_waiting -= 1
            try:
                data = payload if isinstance(payload, dict) else payload.to_json()
                (self._on_event if is_event else self._on_state)(data)
            except Exception:  # noqa: BLE001 — a listener's bug must not stop the deliveries
                pass

    # ------------------------------------------------------------------ threaded mode
    def start(self) -> Outbox:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="hitch-outbox", daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout_s: float = 0.5) -> None:
        """Deliver what is left (bounded by ``timeout_s``) and end the thread."""
        t = self._thread
        if t is None:
            return
        self._stop.set()
        self._wake.set()
        if t is not threading.current_thread():
            t.join(timeout_s)
        self._thread = None
        self._drain()

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.1)
            self._wake.clear()
            self._drain()
