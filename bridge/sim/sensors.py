"""The tractor's sensors in the twin: CAN payloads from a :class:`~bridge.sim.terrain.TerrainTwin`.

Pure functions of time (and of the implement sensor's height, which the hitch pose gives):

* :meth:`TwinSensors.slope` — SAE J1939 Slope Sensor Information (PGN 61459) from the slope
  sensor on the tractor body: pitch, roll, pitch rate, figures of merit, latency;
* :meth:`TwinSensors.wheel_speed` — ISO 11783-7 wheel-based speed and distance (PGN 65096), the
  generalisation of :class:`bridge.service.odometer.SimulatedTractor` to a speed profile;
* :meth:`TwinSensors.ground_distance` — the implement's ground-distance sensor (proprietary 0xFF26);
* :meth:`TwinSensors.ground_ahead` — the look-ahead ground-distance sensor on the tractor's front
  (the same 0xFF26 from its own sender, :data:`~bridge.isobus.messages.GROUND_AHEAD_SENSOR_ADDRESS`);
* :meth:`TwinSensors.row_guidance` — the crop-row camera (proprietary 0xFF27), held between its
  10 Hz samples.

Values outside what a message can carry are reported as "not available" (figure of merit ERROR),
never clipped into a wrong number. The periods are the messages' DBC cycle times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bridge.isobus.j1939 import MachineDirection, Switch
from bridge.isobus.messages import (
    FigureOfMerit,
    GroundDistance,
    RowGuidance,
    SlopeSensorInformation,
    WheelBasedSpeed,
)
from bridge.sim.terrain import TerrainError, TerrainTwin

__all__ = ["DISTANCE_WRAP_M", "SLOPE_PERIOD_S", "WHEEL_SPEED_PERIOD_S", "GROUND_PERIOD_S", "TwinSensors"]

DISTANCE_WRAP_M = 4_211_081.215
"""The wheel-based distance field wraps here (32 bits at 1 mm), as :mod:`bridge.service.odometer`."""
SLOPE_PERIOD_S = 0.01
WHEEL_SPEED_PERIOD_S = 0.1
GROUND_PERIOD_S = 0.02

_SSI_ANGLE_LIMIT_RAD = math.radians(64.0)
_SSI_LATENCY_LIMIT_S = 0.125
_GROUND_LIMIT_M = 6.4255
_ROW_LIMIT_M = 3.2


@dataclass(frozen=True)
class TwinSensors:
    """The sensor payloads of one :class:`TerrainTwin`.

    Attributes:
        twin: the terrain twin.
        slope_latency_s: the latency the slope sensor reports (0..0.125 s); its angles are those
            of ``t - slope_latency_s``.
    """

    twin: TerrainTwin
    slope_latency_s: float = 0.01

    def __post_init__(self) -> None:
        v = self.slope_latency_s
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= _SSI_LATENCY_LIMIT_S:
            raise TerrainError(f"slope_latency_s must be a number in [0, {_SSI_LATENCY_LIMIT_S}] s, got {v!r}")

    @property
    def row_period_s(self) -> float:
        return 1.0 / self.twin.row.rate_hz

    def slope(self, t: float) -> SlopeSensorInformation:
        """PGN 61459 at time ``t``: the attitude of ``t - slope_latency_s``."""
        st = self.twin.state(max(0.0, t - self.slope_latency_s))

        def angle(value: float) -> tuple[float | None, FigureOfMerit]:
            if abs(value) < _SSI_ANGLE_LIMIT_RAD:
                return value, FigureOfMerit.FULLY_FUNCTIONAL
            return None, FigureOfMerit.ERROR

        pitch, pitch_merit = angle(st.pitch_rad)
        roll, roll_merit = angle(st.roll_rad)
        rate, rate_merit = angle(st.pitch_rate_rad_s)
        return SlopeSensorInformation(
            pitch_rad=pitch,
            roll_rad=roll,
            pitch_rate_rad_s=rate,
            pitch_merit=pitch_merit,
            roll_merit=roll_merit,
            pitch_rate_merit=rate_merit,
            compensated=Switch.ON,
            latency_s=round(self.slope_latency_s * 2000.0) / 2000.0,
        )

    def wheel_speed(self, t: float) -> WheelBasedSpeed:
        """PGN 65096 at time ``t``: speed and the distance travelled (mm, wrapped), forward."""
        return WheelBasedSpeed(
            speed_m_s=self.twin.speed.speed_m_s(t),
            distance_m=round(self.twin.distance_m(t) % DISTANCE_WRAP_M, 3),
            direction=MachineDirection.FORWARD,
        )

    def ground_distance(
        self, t: float, sensor_height_m: float, *, behind_m: float | None = None, lateral_m: float = 0.0
    ) -> GroundDistance:
        """0xFF26 at ``t`` for a sensor ``sensor_height_m`` above the tractor's contact plane."""
        d = self.twin.ground_distance_m(t, sensor_height_m, behind_m=behind_m, lateral_m=lateral_m)
        if not 0.0 <= d <= _GROUND_LIMIT_M:
            return GroundDistance(None, FigureOfMerit.ERROR)
        return GroundDistance(d, FigureOfMerit.FULLY_FUNCTIONAL)

    def ground_ahead(self, t: float) -> GroundDistance:
        """0xFF26 of the look-ahead ground sensor at ``t`` (:class:`~bridge.sim.terrain.LookAheadGroundSensor`);
        "not available" when none is fitted."""
        if not self.twin.ground_sensor.fitted:
            return GroundDistance(None, FigureOfMerit.NOT_AVAILABLE)
        d = self.twin.ground_ahead_distance_m(t)
        if not 0.0 <= d <= _GROUND_LIMIT_M:
            return GroundDistance(None, FigureOfMerit.ERROR)
        return GroundDistance(d, FigureOfMerit.FULLY_FUNCTIONAL)

    def row_guidance(self, t: float) -> RowGuidance:
        """0xFF27 at ``t``: the camera's last sample (updated at the row signal's rate)."""
        v = self.twin.row_measured_offset_m(t)
        if not -_ROW_LIMIT_M <= v <= _ROW_LIMIT_M:
            return RowGuidance(None, FigureOfMerit.ERROR)
        return RowGuidance(v, FigureOfMerit.FULLY_FUNCTIONAL)
