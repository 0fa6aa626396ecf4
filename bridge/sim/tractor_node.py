"""The twin's tractor on the bus: its sensors' CAN messages from a :class:`~bridge.sim.sensors.TwinSensors`.

:class:`TractorTwinNode` is a bus node (``start``, ``poll``, ``handle``, ``next_due_s``, ``bus``, the
:class:`bridge.link.realtime.BusNode` protocol) that sends, in node time (s since :meth:`start`):

============================  =========  ======  ====================================================
message                       PGN        period  from
============================  =========  ======  ====================================================
wheel-based speed, distance   65096      100 ms  tractor ECU (240)
Slope Sensor Information      61459      10 ms   slope sensor (226)
implement ground distance     0xFF26     20 ms   ground-distance sensor (227)
crop-row lateral offset       0xFF27     camera  row camera (228), at the camera's rate (10 Hz default)
look-ahead ground distance    0xFF26     20 ms   look-ahead ground sensor (230), only when the twin has one
============================  =========  ======  ====================================================

The periods are the DBC cycle times (``docs/sensors.md``); each can be changed or switched off
(None) in :class:`TractorNodeConfig`. A message is sent at the first poll at or after its due time,
then due one period later (never a burst to catch up: after a stall it re-anchors on the poll).
Nothing reads the wall clock: the node runs in simulated time (polled by a test or a rig tick by
tick) and in real time under :class:`~bridge.link.realtime.RealtimeRunner`.

Two ways to build it:

* from a terrain twin: ``TractorTwinNode(bus, TwinSensors(twin))`` or
  :meth:`TractorTwinNode.from_scenario` (a built-in name or a TOML path); every value is the
  twin's pure function of node time;
* flat and level at a constant ground speed: ``TractorTwinNode(bus, ground_speed_m_s=v)``
  (0..64 m/s, the wheel-speed field's range). Its PGN 65096 frames are those of the former
  constant-speed ``SimulatedTractor``, byte for byte: the distance is accumulated over the polls
  as ``(d + v·Δt) mod 4 211 081.215 m`` and sent rounded to 1 mm, forward; slope 0, row offset 0.

The ground distance needs the height of the implement's ground sensor above the tractor's ground
contact plane: ``hitch_height_m(t)`` gives it in metres at node time ``t`` (the rig or service
takes it from the simulated ECU's true pose, e.g. :func:`hitch_height_from_ecu`). None — no
callable, or the callable returns None — sends "not available" (figure of merit NOT_AVAILABLE);
a non-finite height, one the twin refuses, or a :class:`~planner.errors.HitchError` from the
callable sends the error figure of merit. The node never raises out of ``poll`` for a bad sample
(a dead CAN thread ends the service); it counts it in :attr:`TractorTwinNode.encode_errors`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can

from bridge.isobus.codec import encode
from bridge.isobus.j1939 import TRACTOR_ECU_ADDRESS, MachineDirection
from bridge.isobus.messages import (
    GROUND_AHEAD_SENSOR_ADDRESS,
    GROUND_SENSOR_ADDRESS,
    ROW_CAMERA_ADDRESS,
    SLOPE_SENSOR_ADDRESS,
    FigureOfMerit,
    GroundDistance,
    Payload,
    WheelBasedSpeed,
)
from bridge.sim.scenario import Scenario, load_scenario
from bridge.sim.sensors import DISTANCE_WRAP_M, GROUND_PERIOD_S, SLOPE_PERIOD_S, WHEEL_SPEED_PERIOD_S, TwinSensors
from bridge.sim.terrain import RowSignal, SpeedProfile, TerrainTwin
from planner.errors import HitchError, HitchInputError

if TYPE_CHECKING:
    from bridge.sim.ecu import CylinderECU
    from planner.model.kinematics import HitchModel

__all__ = [
    "MAX_GROUND_SPEED_M_S",
    "STREAMS",
    "TractorNodeConfig",
    "TractorNodeError",
    "TractorTwinNode",
    "hitch_height_from_ecu",
]

MAX_GROUND_SPEED_M_S = 64.0
"""Largest constant ground speed of the flat default (the 65096 speed field carries 0..64.255 m/s)."""

STREAMS = ("wheel_speed", "slope", "ground", "row", "ground_ahead")
"""The node's messages, in the order they are sent within one poll."""

HitchHeight = Callable[[float], float | None]
"""Height [m] of the implement's ground sensor above the tractor's contact plane at node time t (s)."""


class TractorNodeError(HitchInputError):
    """A setting of the tractor twin node out of its range (named in the message)."""


def _period(name: str, value: object, *, optional: bool = True) -> None:
    if value is None and optional:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.005 <= value <= 1.0:
        allowed = "None (the camera's rate) or a number" if optional else "a number"
        raise TractorNodeError(f"{name} must be {allowed} in [0.005, 1] s, got {value!r}")


def _address(name: str, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 253:
        raise TractorNodeError(f"{name} must be a source address in [0, 253], got {value!r}")


@dataclass(frozen=True)
class TractorNodeConfig:
    """Periods [s] and source addresses of the node's messages.

    Attributes:
        wheel_speed_period_s: PGN 65096 (default 0.1 s, ISO 11783-7's 100 ms).
        slope_period_s: SSI, PGN 61459 (default 0.01 s, the DBC cycle time and the manuals' default).
        ground_period_s: ground distance 0xFF26 (default 0.02 s), also the look-ahead ground sensor's
            (sent only when the twin has one: :attr:`bridge.sim.terrain.TerrainTwin.ground_sensor`).
        row_period_s: crop-row offset 0xFF27; None here means *at the camera's rate*
            (``1 / row.rate_hz`` of the twin, 10 Hz in every built-in scenario); to switch the
            row message off, leave it out of ``streams``.
        streams: which of :data:`STREAMS` are sent.
        ground_behind_m, ground_lateral_m: the ground sensor's point, behind the rear axle (None:
            the twin's ``implement_behind_m``) and to the left [m].
        wheel_source, slope_source, ground_source, row_source, ground_ahead_source: source addresses.
    """

    wheel_speed_period_s: float = WHEEL_SPEED_PERIOD_S
    slope_period_s: float = SLOPE_PERIOD_S
    ground_period_s: float = GROUND_PERIOD_S
    row_period_s: float | None = None
    streams: tuple[str, ...] = STREAMS
    ground_behind_m: float | None = None
    ground_lateral_m: float = 0.0
    wheel_source: int = TRACTOR_ECU_ADDRESS
    slope_source: int = SLOPE_SENSOR_ADDRESS
    ground_source: int = GROUND_SENSOR_ADDRESS
    row_source: int = ROW_CAMERA_ADDRESS
    ground_ahead_source: int = GROUND_AHEAD_SENSOR_ADDRESS

    def __post_init__(self) -> None:
        for name in ("wheel_speed_period_s", "slope_period_s", "ground_period_s"):
            _period(name, getattr(self, name), optional=False)
        _period("row_period_s", self.row_period_s)
        if not isinstance(self.streams, tuple) or any(s not in STREAMS for s in self.streams):
            raise TractorNodeError(f"streams must be a tuple of {', '.join(STREAMS)}, got {self.streams!r}")
        b = self.ground_behind_m
        if b is not None and (isinstance(b, bool) or not isinstance(b, (int, float)) or not 0.0 <= b <= 10.0):
            raise TractorNodeError(f"ground_behind_m must be None or a number in [0, 10] m, got {b!r}")
        u = self.ground_lateral_m
        if isinstance(u, bool) or not isinstance(u, (int, float)) or not -5.0 <= u <= 5.0:
            raise TractorNodeError(f"ground_lateral_m must be a number in [-5, 5] m, got {u!r}")
        for name in ("wheel_source", "slope_source", "ground_source", "row_source", "ground_ahead_source"):
            _address(name, getattr(self, name))


def flat_sensors() -> TwinSensors:
    """Flat level ground, a straight row without camera noise, standing still (the default's twin)."""
    return TwinSensors(TerrainTwin(speed=SpeedProfile.constant(0.0), row=RowSignal(rms_m=0.0, noise_rms_m=0.0)))


@dataclass
class _Stream:
    name: str
    period_s: float
    source: int
    due_s: float = 0.0
    sent: int = 0


class TractorTwinNode:
    """The twin's tractor sensors as a bus node (module docstring).

    Args:
        bus: the node's bus (it only sends; received frames are discarded).
        sensors: the twin's sensors; or None with ``ground_speed_m_s``.
        ground_speed_m_s: the flat default at this constant speed (0..64 m/s); exclusive with ``sensors``.
        hitch_height_m: ground-sensor height above the contact plane at node time t, or None.
        config: periods, streams, addresses (default :class:`TractorNodeConfig`).
    """

    def __init__(
        self,
        bus: can.BusABC,
        sensors: TwinSensors | None = None,
        *,
        ground_speed_m_s: float | None = None,
        hitch_height_m: HitchHeight | None = None,
        config: TractorNodeConfig | None = None,
    ) -> None:
        v = ground_speed_m_s
        if (sensors is None) == (v is None):
            raise TractorNodeError("give exactly one of sensors (a TwinSensors) or ground_speed_m_s (flat default)")
        if v is not None:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise TractorNodeError(f"ground_speed_m_s must be a number in [0, 64] m/s, got {v!r}")
            if not 0.0 <= v <= MAX_GROUND_SPEED_M_S:
                raise TractorNodeError(f"ground_speed_m_s must be a number in [0, 64] m/s, got {v!r}")
            sensors = flat_sensors()
        elif not isinstance(sensors, TwinSensors):
            raise TractorNodeError(f"sensors must be a TwinSensors, got {type(sensors).__name__}")
        c = TractorNodeConfig() if config is None else config
        if not isinstance(c, TractorNodeConfig):
            raise TractorNodeError(f"config must be a TractorNodeConfig, got {type(c).__name__}")
        if hitch_height_m is not None and not callable(hitch_height_m):
            raise TractorNodeError("hitch_height_m must be a callable t -> height [m] or None")
        self._bus = bus
        self.sensors: TwinSensors = sensors
        self.ground_speed_m_s: float | None = None if v is None else float(v)
        self.hitch_height_m = hitch_height_m
        self.config = c
        self.encode_errors = 0
        """Samples that could not be encoded (counted, never raised)."""
        self.send_errors = 0
        """Frames the bus refused (``can.CanError``)."""
        row_period = c.row_period_s if c.row_period_s is not None else sensors.row_period_s
        periods = {
            "wheel_speed": (c.wheel_speed_period_s, c.wheel_source),
            "slope": (c.slope_period_s, c.slope_source),
            "ground": (c.ground_period_s, c.ground_source),
            "row": (row_period, c.row_source),
            "ground_ahead": (c.ground_period_s, c.ground_ahead_source),
        }
        fitted = {"ground_ahead": sensors.twin.ground_sensor.fitted}
        self._streams = tuple(
            _Stream(n, float(periods[n][0]), periods[n][1]) for n in STREAMS if n in c.streams and fitted.get(n, True)
        )
        self._t0: float | None = None
        self._t_last = 0.0
        self._distance = 0.0

    @classmethod
    def from_scenario(
        cls,
        bus: can.BusABC,
        scenario: Scenario | str | Path,
        *,
        hitch_height_m: HitchHeight | None = None,
        config: TractorNodeConfig | None = None,
        slope_latency_s: float = 0.01,
    ) -> TractorTwinNode:
        """The node of a :class:`~bridge.sim.scenario.Scenario` (or a built-in name / TOML path)."""
        sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        return cls(
            bus,
            TwinSensors(sc.twin, slope_latency_s=slope_latency_s),
            hitch_height_m=hitch_height_m,
            config=config if config is not None else TractorNodeConfig(),
        )

    # -- BusNode ---------------------------------------------------------------------------
    @property
    def bus(self) -> can.BusABC:
        return self._bus

    @property
    def started_s(self) -> float | None:
        """The node time of :meth:`start` (the twin's t = 0), None before."""
        return self._t0

    def sent(self, stream: str) -> int:
        """Frames of ``stream`` (one of :data:`STREAMS`) sent so far."""
        return sum(s.sent for s in self._streams if s.name == stream)

    def start(self, now_s: float) -> None:
        """The twin's time 0 is ``now_s``; every message is due at once."""
        self._t0 = self._t_last = now_s
        for s in self._streams:
            s.due_s = now_s

    def next_due_s(self) -> float:
        if not self._streams:
            return self._t_last + 1.0
        return min(s.due_s for s in self._streams)

    def handle(self, frame: can.Message, now_s: float) -> None:  # a sender only
        return None

    def poll(self, now_s: float) -> None:
        while self._bus.recv(timeout=0.0) is not None:  # keep the receive queue empty
            pass
        if self._t0 is None:
            self.start(now_s)  # nothing travelled yet
            elapsed = 0.0
        else:
            elapsed = now_s - self._t_last
        if self.ground_speed_m_s is not None:  # the former SimulatedTractor's sum, operation for operation
            self._distance = (self._distance + self.ground_speed_m_s * elapsed) % DISTANCE_WRAP_M
        self._t_last = now_s
        assert self._t0 is not None
        t = now_s - self._t0
        for s in self._streams:
            if now_s + 1e-9 >= s.due_s:
                s.due_s += s.period_s
                if s.due_s <= now_s + 1e-9:  # late by a period or more: the next time on its grid after now
                    s.due_s += math.ceil((now_s + 2e-9 - s.due_s) / s.period_s) * s.period_s
                self._send(s, t)

    # -- payloads --------------------------------------------------------------------------
    def payload(self, stream: str, t: float) -> Payload:
        """The payload of ``stream`` at twin time ``t`` (s since :meth:`start`)."""
        sensors = self.sensors
        if stream == "wheel_speed":
            if self.ground_speed_m_s is not None:
                return WheelBasedSpeed(
                    speed_m_s=self.ground_speed_m_s,
                    distance_m=round(self._distance, 3),
                    direction=MachineDirection.FORWARD,
                )
            return sensors.wheel_speed(t)
        if stream == "slope":
            return sensors.slope(t)
        if stream == "ground":
            return self._ground(sensors, t)
        if stream == "row":
            return sensors.row_guidance(t)
        if stream == "ground_ahead":
            return sensors.ground_ahead(t)
        raise TractorNodeError(f"stream must be one of {', '.join(STREAMS)}, got {stream!r}")

    def _ground(self, sensors: TwinSensors, t: float) -> GroundDistance:
        if self.hitch_height_m is None:
            return GroundDistance(None, FigureOfMerit.NOT_AVAILABLE)
        try:
            h = self.hitch_height_m(t)
            if h is None:
                return GroundDistance(None, FigureOfMerit.NOT_AVAILABLE)
            if isinstance(h, bool) or not isinstance(h, (int, float)) or not math.isfinite(h):
                return GroundDistance(None, FigureOfMerit.ERROR)
            c = self.config
            return sensors.ground_distance(t, float(h), behind_m=c.ground_behind_m, lateral_m=c.ground_lateral_m)
        except HitchError:  # a height the twin refuses, a pose that cannot be computed
            return GroundDistance(None, FigureOfMerit.ERROR)

    def _send(self, s: _Stream, t: float) -> None:
        try:
            frame = encode(self.payload(s.name, t), source=s.source)
        except HitchError:  # a value the message cannot carry: counted, never ends the node
            self.encode_errors += 1
            return
        try:
            self._bus.send(frame)
        except can.CanError:
            self.send_errors += 1
            return
        s.sent += 1


def hitch_height_from_ecu(
    ecu: CylinderECU, model: HitchModel, *, sensor_offset_m: float = 0.0
) -> Callable[[float], float | None]:
    """``hitch_height_m`` from the simulated ECU's true (noise-free) piston positions.

    Height of the ground sensor above the contact plane = the profile's lower-link pivot height
    above the ground + the tool point's z (tractor frame, origin at pivot height) + ``sensor_offset_m``
    (the sensor's height relative to the tool point, negative below it). None while the pose
    cannot be computed (a position outside the model's reach). Reads the ECU without its node's
    lock: in real time the pistons may be one 1 ms step apart — immaterial for a height sensor.
    """
    if isinstance(sensor_offset_m, bool) or not isinstance(sensor_offset_m, (int, float)):
        raise TractorNodeError(f"sensor_offset_m must be a number in [-3, 3] m, got {sensor_offset_m!r}")
    if not -3.0 <= sensor_offset_m <= 3.0:
        raise TractorNodeError(f"sensor_offset_m must be a number in [-3, 3] m, got {sensor_offset_m!r}")
    base = float(model.profile.geometry.pivot_height) + float(sensor_offset_m)
    last: list[Any] = [(None, None)]  # (piston positions, their height), one cell: a hitch at rest costs no kinematics

    def height(t: float) -> float | None:
        counts = tuple(ecu.piston_counts().tolist())
        seen, seen_h = last[0]
        if counts == seen:
            return seen_h
        try:
            q = [p.counts_to_si(float(c)) for p, c in zip(ecu.params, counts, strict=True)]
            h: float | None = base + float(model.pose(q).z)
        except HitchError:
            h = None
        last[0] = (counts, h)
        return h

    return height
