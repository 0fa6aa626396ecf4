"""Distance travelled by the tractor, from ISO 11783-7 wheel-based speed and distance (PGN 65096).

Maneuver ``wait_for`` steps wait for metres travelled. The tractor ECU sends PGN
65096 (speed 0.001 m/s/bit, distance 0.001 m/bit, wrapping at 4 211 081.215 m) about every
100 ms. :class:`WheelOdometer` listens on the CAN bus and accumulates the distance field's
increments (wrap-around handled; when the field is unavailable it integrates the speed), so
its :meth:`~WheelOdometer.distance_m` starts at 0 when the service starts. It reports None
before the first frame and when the tractor has been silent for ``stale_after_s`` — a
``wait_for`` then keeps waiting and the maneuver's timeout ends it.

:class:`SimulatedTractor` is the other side for the simulated machine: it sends PGN 65096 from
the tractor ECU's address at a constant ground speed — the flat default of
:class:`bridge.sim.tractor_node.TractorTwinNode` with only its wheel-speed message (the twin's
tractor with slope, ground-distance and row messages is that node). Both are bus nodes
(``start``, ``poll``, ``handle``, ``next_due_s``, ``bus``) driven by
:class:`bridge.link.realtime.RealtimeRunner`. The accumulation of the distance is
:class:`bridge.link.tractor_sensors.WheelDistance`, shared with
:class:`~bridge.link.tractor_sensors.TractorSensors` (which reads every tractor sensor).
"""

from __future__ import annotations

import math

import can

from bridge.isobus.codec import CodecError, WheelBasedSpeed, decode_frame
from bridge.isobus.j1939 import PGN_WHEEL_BASED_SPEED, TRACTOR_ECU_ADDRESS, decode_id
from bridge.link.realtime import ReceivingNode
from bridge.link.tractor_sensors import DISTANCE_WRAP_M, WheelDistance
from bridge.sim.tractor_node import TractorNodeConfig, TractorTwinNode
from planner.errors import HitchInputError

__all__ = ["WheelOdometer", "SimulatedTractor", "OdometerError", "DISTANCE_WRAP_M"]


class OdometerError(HitchInputError):
    """A setting of the odometer or the simulated tractor out of its range (named in the message)."""


class WheelOdometer(ReceivingNode):
    """Cumulative distance [m] from PGN 65096 frames of ``source`` (None: any sender)."""

    poll_period_s = 0.1

    def __init__(self, bus: can.BusABC, *, source: int | None = TRACTOR_ECU_ADDRESS, stale_after_s: float = 1.0):
        if not 0.05 <= stale_after_s <= 60.0:
            raise OdometerError(f"stale_after_s must lie within [0.05, 60] s, got {stale_after_s!r}")
        self._bus = bus
        self.source = source
        self.stale_after_s = float(stale_after_s)
        self._wheel = WheelDistance()
        self._now = 0.0
        self.frames = 0
        self.malformed = 0

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
        """Add the travel since the previous frame (distance field, else speed × time; a step of
        1000 m or more is a reset of the sender's odometer, not travel)."""
        self._wheel.add(p.distance_m, p.speed_m_s, now_s)
        self.frames += 1

    def distance_m(self) -> float | None:
        """Metres travelled since start; None before the first frame or when the tractor is silent."""
        last = self._wheel.last_t
        if last is None or self._now - last > self.stale_after_s:
            return None
        return self._wheel.total_m


class SimulatedTractor(TractorTwinNode):
    """Sends PGN 65096 at ``speed_m_s`` (forward) every ``period_s`` from the tractor ECU (240).

    The flat default of :class:`~bridge.sim.tractor_node.TractorTwinNode` with the wheel-speed
    message only (frames byte for byte those of the constant-speed tractor it replaced).
    """

    def __init__(self, bus: can.BusABC, speed_m_s: float, *, period_s: float = 0.1, source: int = TRACTOR_ECU_ADDRESS):
        if not (
            isinstance(speed_m_s, (int, float))
            and not isinstance(speed_m_s, bool)
            and math.isfinite(speed_m_s)
            and 0.0 <= speed_m_s <= 64.0
        ):
            raise OdometerError(f"speed_m_s must be a number in [0, 64] m/s, got {speed_m_s!r}")
        if isinstance(period_s, bool) or not isinstance(period_s, (int, float)) or not 0.01 <= period_s <= 1.0:
            raise OdometerError(f"period_s must lie within [0.01, 1] s, got {period_s!r}")
        if isinstance(source, bool) or not isinstance(source, int) or not 0 <= source <= 253:
            raise OdometerError(f"source must be a source address in [0, 253], got {source!r}")
        config = TractorNodeConfig(wheel_speed_period_s=float(period_s), streams=("wheel_speed",), wheel_source=source)
        super().__init__(bus, ground_speed_m_s=float(speed_m_s), config=config)
        self.speed_m_s, self.period_s, self.source = float(speed_m_s), float(period_s), source
