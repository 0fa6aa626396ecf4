"""Distance travelled by the tractor, from ISO 11783-7 wheel-based speed and distance (PGN 65096).

Maneuver ``wait_for`` steps wait for metres travelled. The tractor ECU sends PGN
65096 (speed 0.001 m/s/bit, distance 0.001 m/bit, wrapping at 4 211 081.215 m) about every
100 ms. :class:`WheelOdometer` listens on the CAN bus and accumulates the distance field's
increments (wrap-around handled; when the field is unavailable it integrates the speed), so
its :meth:`~WheelOdometer.distance_m` starts at 0 when the service starts. It reports None
before the first frame and when the tractor has been silent for ``stale_after_s`` — a
``wait_for`` then keeps waiting and the maneuver's timeout ends it.

:class:`SimulatedTractor` is the other side for the simulated machine: it sends PGN 65096 from
the tractor ECU's address at a constant ground speed. Both are bus nodes (``start``, ``poll``,
``handle``, ``next_due_s``, ``bus``) driven by :class:`bridge.link.realtime.RealtimeRunner`.
"""

from __future__ import annotations

import math

import can

from bridge.isobus.codec import CodecError, WheelBasedSpeed, decode_frame, encode
from bridge.isobus.j1939 import PGN_WHEEL_BASED_SPEED, TRACTOR_ECU_ADDRESS, MachineDirection, decode_id
from planner.errors import HitchInputError

__all__ = ["WheelOdometer", "SimulatedTractor", "OdometerError", "DISTANCE_WRAP_M"]

#: the distance field's range (32 bits at 0.001 m): it wraps here
DISTANCE_WRAP_M = 4_211_081.215


class OdometerError(HitchInputError):
    """A setting of the odometer or the simulated tractor out of its range (named in the message)."""


class WheelOdometer:
    """Cumulative distance [m] from PGN 65096 frames of ``source`` (None: any sender)."""

    def __init__(self, bus: can.BusABC, *, source: int | None = TRACTOR_ECU_ADDRESS, stale_after_s: float = 1.0):
        if not 0.05 <= stale_after_s <= 60.0:
            raise OdometerError(f"stale_after_s must lie within [0.05, 60] s, got {stale_after_s!r}")
        self._bus = bus
        self.source = source
        self.stale_after_s = float(stale_after_s)
        self._total = 0.0
        self._last_field: float | None = None
        self._last_t: float | None = None
        self._last_speed: float | None = None
        self._now = 0.0
        self.frames = 0
        self.malformed = 0

    @property
    def bus(self) -> can.BusABC:
        return self._bus

    def start(self, now_s: float) -> None:
        self._now = now_s

    def next_due_s(self) -> float:
        return self._now + 0.1

    def poll(self, now_s: float) -> None:
        self._now = now_s
        while (frame := self._bus.recv(timeout=0.0)) is not None:
            self.take(frame, now_s)

    def handle(self, frame: can.Message, now_s: float) -> None:
        """A frame from the bus (the :class:`~bridge.link.realtime.BusNode` hook): see :meth:`take`."""
        self.take(frame, now_s)

    def take(self, frame: can.Message, now_s: float) -> bool:
        """Take one frame; True if it was a wheel-based speed frame we accepted."""
        self._now = now_s
        if not frame.is_extended_id or frame.is_error_frame:
            return False
        try:
            ident = decode_id(frame.arbitration_id)
        except ValueError:
            return False
        if ident.pgn != PGN_WHEEL_BASED_SPEED or (self.source is not None and ident.source_address != self.source):
            return False
        try:
            p = decode_frame(frame).payload
        except CodecError:
            self.malformed += 1
            return False
        if not isinstance(p, WheelBasedSpeed):
            return False
        self.accept(p, now_s)
        return True

    def accept(self, p: WheelBasedSpeed, now_s: float) -> None:
        """Add the travel since the previous frame (distance field, else speed × time)."""
        if p.distance_m is not None:
            if self._last_field is not None:
                step = (p.distance_m - self._last_field) % DISTANCE_WRAP_M
                if step < 1000.0:  # a reset of the sender's odometer is not travel
                    self._total += step
            self._last_field = p.distance_m
        elif p.speed_m_s is not None and self._last_t is not None and self._last_speed is not None:
            self._total += 0.5 * (p.speed_m_s + self._last_speed) * max(0.0, now_s - self._last_t)
        self._last_speed = p.speed_m_s
        self._last_t = now_s
        self.frames += 1

    def distance_m(self) -> float | None:
        """Metres travelled since start; None before the first frame or when the tractor is silent."""
        if self._last_t is None or self._now - self._last_t > self.stale_after_s:
            return None
        return self._total


class SimulatedTractor:
    """Sends PGN 65096 at ``speed_m_s`` (forward) every ``period_s`` from the tractor ECU (240)."""

    def __init__(self, bus: can.BusABC, speed_m_s: float, *, period_s: float = 0.1, source: int = TRACTOR_ECU_ADDRESS):
        if not (isinstance(speed_m_s, (int, float)) and math.isfinite(speed_m_s) and 0.0 <= speed_m_s <= 64.0):
            raise OdometerError(f"speed_m_s must be a number in [0, 64] m/s, got {speed_m_s!r}")
        if not 0.01 <= period_s <= 1.0:
            raise OdometerError(f"period_s must lie within [0.01, 1] s, got {period_s!r}")
        self._bus = bus
        self.speed_m_s, self.period_s, self.source = float(speed_m_s), float(period_s), source
        self._distance = 0.0
        self._t_last: float | None = None
        self._due = 0.0

    @property
    def bus(self) -> can.BusABC:
        return self._bus

    def start(self, now_s: float) -> None:
        self._t_last, self._due = now_s, now_s

    def next_due_s(self) -> float:
        return self._due

    def handle(self, frame: can.Message, now_s: float) -> None:  # a sender only
        return None

    def poll(self, now_s: float) -> None:
        while self._bus.recv(timeout=0.0) is not None:  # keep the receive queue empty
            pass
        if self._t_last is None:
            self.start(now_s)  # nothing travelled yet
            elapsed = 0.0
        else:
            elapsed = now_s - self._t_last
        self._distance = (self._distance + self.speed_m_s * elapsed) % DISTANCE_WRAP_M
        self._t_last = now_s
        if now_s + 1e-9 >= self._due:
            self._due = max(self._due + self.period_s, now_s)
            msg = WheelBasedSpeed(
                speed_m_s=self.speed_m_s, distance_m=round(self._distance, 3), direction=MachineDirection.FORWARD
            )
            try:
                self._bus.send(encode(msg, source=self.source))
            except can.CanError:
                pass
