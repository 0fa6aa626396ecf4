"""Fault injection in the twin: the simulated ECU's bus goes through :class:`FaultInjector`.

The simulated ECU node (:class:`~bridge.sim.can_node.EcuCanNode`) sees planner frames only
through the injector's ``recv`` and its own frames reach the bus only through the injector's
``send``, so every fault is one the planner side must detect from the bus alone:

* ``cut``: ``"planner_to_ecu"`` drops every frame the ECU would receive, ``"ecu_to_planner"``
  every frame it sends, ``"both"`` both (a cut cable), ``"none"`` neither;
* ``loss``: each frame, in either direction, is dropped with this probability (seeded);
* ``delay_ms``: each frame that survives is held this long, in either direction (a slow
  gateway; frames keep their order);
* ``restart_ecu``: the node restarts the ECU once (see :meth:`EcuCanNode.apply_fault`).

Settings change at run time (:meth:`FaultInjector.apply`, thread-safe): a cut or loss
applies to every frame from then on (frames already held by a delay are checked again when
they leave), a new delay to frames that enter from then on.

Time: delays are measured on ``clock`` (``time.monotonic`` in real time; the simulated
clock in :class:`~bridge.sim.rig.SimRig`). Received frames are timestamped when the
injector reads them from the wrapped bus; held outgoing frames leave at the next
:meth:`FaultInjector.flush` at or after their due time (the node flushes at every poll,
so at least every measurement period).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields

import can
import numpy as np

from planner.errors import HitchInputError

__all__ = ["CUTS", "MAX_DELAY_MS", "FaultCounters", "FaultError", "FaultInjector", "FaultSettings"]

#: Allowed values of :attr:`FaultSettings.cut`.
CUTS = ("none", "planner_to_ecu", "ecu_to_planner", "both")

#: Largest allowed :attr:`FaultSettings.delay_ms`.
MAX_DELAY_MS = 5000.0


class FaultError(HitchInputError):
    """Bad fault-injection settings; the message names the field and the allowed range."""


@dataclass(frozen=True)
class FaultSettings:
    """Faults the twin's bus injects (see the module docstring).

    Attributes:
        cut: which direction is cut: one of :data:`CUTS`.
        loss: probability that a frame is lost, in [0, 1] (each direction).
        delay_ms: extra latency of every frame, ms, in [0, 5000] (each direction).
        restart_ecu: restart the simulated ECU once when these settings are applied
            (restart counter +1, no-reference bit set, address claimed again).
    """

    cut: str = "none"
    loss: float = 0.0
    delay_ms: float = 0.0
    restart_ecu: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.cut, str) or self.cut not in CUTS:
            raise FaultError(f"cut must be one of {', '.join(CUTS)}, got {self.cut!r}")
        for name, high, unit in (("loss", 1.0, ""), ("delay_ms", MAX_DELAY_MS, " ms")):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not 0 <= v <= high:
                raise FaultError(f"{name} must be a number in [0, {high:g}]{unit}, got {v!r}")
            object.__setattr__(self, name, float(v))
        if not isinstance(self.restart_ecu, bool):
            raise FaultError(f"restart_ecu must be true or false, got {self.restart_ecu!r}")

    @classmethod
    def from_mapping(cls, data: Mapping[str, object]) -> FaultSettings:
        """Settings from a JSON object ``{"cut", "loss", "delay_ms", "restart_ecu"}``; missing
        keys take their defaults (no fault), unknown keys are refused."""
        if not isinstance(data, Mapping):
            raise FaultError(f"fault settings must be an object with keys {_KEYS}, got {type(data).__name__}")
        unknown = sorted(str(k) for k in data if k not in _KEYS)
        if unknown:
            raise FaultError(f"unknown fault setting(s) {unknown}; allowed {list(_KEYS)}")
        return cls(**{str(k): v for k, v in data.items()})  # type: ignore[arg-type]

    def to_json(self) -> dict[str, object]:
        """The settings as a JSON object (the keys of :meth:`from_mapping`)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def planner_to_ecu_cut(self) -> bool:
        """Frames to the ECU are all dropped."""
        return self.cut in ("planner_to_ecu", "both")

    @property
    def ecu_to_planner_cut(self) -> bool:
        """Frames from the ECU are all dropped."""
        return self.cut in ("ecu_to_planner", "both")


_KEYS = tuple(f.name for f in fields(FaultSettings))


@dataclass(frozen=True)
class FaultCounters:
    """What the injector did to frames (monotonic).

    ``*_dropped``: lost by a cut or by ``loss``; ``*_delayed``: held by ``delay_ms``;
    ``rx``: planner → ECU, ``tx``: ECU → planner.
    """

    rx_passed: int = 0
    rx_dropped: int = 0
    rx_delayed: int = 0
    tx_passed: int = 0
    tx_dropped: int = 0
    tx_delayed: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


class FaultInjector(can.BusABC):
    """Wraps the simulated ECU's bus and injects :class:`FaultSettings` in both directions.

    The wrapped bus belongs to its owner: :meth:`shutdown` leaves it open.

    Args:
        inner: the bus the ECU node would otherwise use.
        settings: initial faults (default none: every frame passes at once).
        seed: seed of the frame loss.
        clock: seconds of a monotonic clock for the delays (default ``time.monotonic``).
    """

    def __init__(
        self,
        inner: can.BusABC,
        settings: FaultSettings | None = None,
        *,
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._inner = inner
        self._settings = settings if settings is not None else FaultSettings()
        self._rng = np.random.default_rng(seed)
        self._clock = clock
        self._lock = threading.Lock()
        self._rx_held: deque[tuple[float, can.Message]] = deque()
        self._tx_held: deque[tuple[float, can.Message]] = deque()
        self._counters = FaultCounters()
        super().__init__(channel=inner.channel_info)
        self.channel_info = f"fault-injected {inner.channel_info}"

    @property
    def inner(self) -> can.BusABC:
        """The wrapped bus."""
        return self._inner

    @property
    def settings(self) -> FaultSettings:
        """The faults in force."""
        return self._settings

    @property
    def counters(self) -> FaultCounters:
        """What was done to frames so far (a snapshot)."""
        return self._counters

    def apply(self, settings: FaultSettings) -> None:
        """Put ``settings`` in force from now on (thread-safe)."""
        if not isinstance(settings, FaultSettings):
            raise FaultError(f"settings must be a FaultSettings, got {type(settings).__name__}")
        with self._lock:
            self._settings = settings
            if settings.delay_ms == 0.0:  # no delay any more: held frames are due now
                now = self._clock()
                self._rx_held = deque((min(t, now), m) for t, m in self._rx_held)
                self._tx_held = deque((min(t, now), m) for t, m in self._tx_held)

    # -- ECU → planner -----------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        with self._lock:
            s = self._settings
            if s.ecu_to_planner_cut or self._lost(s):
                self._bump(tx_dropped=1)
                return
            if s.delay_ms > 0.0 or self._tx_held:
                self._tx_held.append((self._clock() + s.delay_ms / 1000.0, msg))
                self._bump(tx_delayed=1)
                due = self._due(self._tx_held, tx=True)
            else:
                due = [msg]
        self._send_all(due, timeout)

    def flush(self) -> None:
        """Send the held frames that are due (the node calls this at every poll); a frame the
        wrapped bus refuses is counted as dropped."""
        with self._lock:
            due = self._due(self._tx_held, tx=True)
        for m in due:
            try:
                self._send_all([m], None)
            except can.CanError:
                self._bump(tx_dropped=1)

    def _send_all(self, frames: list[can.Message], timeout: float | None) -> None:
        for m in frames:
            self._inner.send(m, timeout)
            self._bump(tx_passed=1)

    # -- planner → ECU -----------------------------------------------------------------
    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        end = None if timeout is None else time.monotonic() + max(timeout, 0.0)
        while True:
            with self._lock:
                due = self._due(self._rx_held, tx=False, first_only=True)
                if due:
                    return due[0], False
                wait_held = self._rx_held[0][0] - self._clock() if self._rx_held else math.inf
            left = math.inf if end is None else end - time.monotonic()
            wait = max(0.0, min(left, wait_held))
            msg = self._inner.recv(timeout=None if math.isinf(wait) else wait)
            if msg is not None:
                with self._lock:
                    s = self._settings
                    if s.planner_to_ecu_cut or self._lost(s):
                        self._bump(rx_dropped=1)
                    elif s.delay_ms > 0.0 or self._rx_held:
                        self._rx_held.append((self._clock() + s.delay_ms / 1000.0, msg))
                        self._bump(rx_delayed=1)
                    else:
                        self._bump(rx_passed=1)
                        return msg, False
                continue  # dropped or held: read on (a zero timeout drains the queue first)
            if end is not None and time.monotonic() >= end:
                with self._lock:  # a held frame may have fallen due while we waited
                    due = self._due(self._rx_held, tx=False, first_only=True)
                return (due[0] if due else None), False

    # -- internals ---------------------------------------------------------------------
    def _lost(self, s: FaultSettings) -> bool:
        return s.loss > 0.0 and (s.loss >= 1.0 or self._rng.random() < s.loss)

    def _due(self, held: deque[tuple[float, can.Message]], *, tx: bool, first_only: bool = False) -> list[can.Message]:
        """Pop the held frames due now (in order); frames a cut or loss now catches are dropped."""
        out: list[can.Message] = []
        now = self._clock()
        s = self._settings
        cut = s.ecu_to_planner_cut if tx else s.planner_to_ecu_cut
        while held and held[0][0] <= now + 1e-9 and not (first_only and out):
            _, msg = held.popleft()
            if cut:
                self._bump(**{"tx_dropped" if tx else "rx_dropped": 1})
                continue
            if not tx:
                self._bump(rx_passed=1)
            out.append(msg)
        return out

    def _bump(self, **deltas: int) -> None:
        c = self._counters
        values = dict(c.__dict__)  # as dataclasses.replace, without its per-field introspection (per frame)
        for k, v in deltas.items():
            values[k] += v
        self._counters = type(c)(**values)

    def shutdown(self) -> None:
        """Stop using the injector; the wrapped bus stays open (its owner shuts it down)."""
        super().shutdown()

    def __getattr__(self, name: str) -> object:
        """Anything else is the wrapped bus's (e.g. a :class:`~bridge.sim.rig.LossyBus`'s counter)."""
        if name.startswith("__") or name == "_inner":
            raise AttributeError(name)
        return getattr(self._inner, name)

    def __del__(self) -> None:  # holds no OS resource of its own: nothing to warn about
        pass
