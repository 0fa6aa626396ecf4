"""The planner side of the tractor's sensors: their CAN messages into one thread-safe latest snapshot.

:class:`TractorSensors` is a bus node (the :class:`~bridge.link.realtime.BusNode` protocol, driven by
:class:`~bridge.link.realtime.RealtimeRunner` or polled in simulated time) that decodes

* SAE J1939-71 Slope Sensor Information (SSI, PGN 61459): roll, pitch, pitch rate, latency;
* SSI2 (PGN 61481, extended range): roll, pitch (no pitch rate) — whichever of SSI / SSI2 came last wins;
* the implement ground distance (proprietary 0xFF26) and the crop-row offset (0xFF27);
* ISO 11783-7 wheel-based speed and distance (PGN 65096): speed, and the distance travelled since
  start accumulated exactly as :class:`bridge.service.odometer.WheelOdometer` does
  (:class:`WheelDistance`: wrap-around, a sender reset is not travel, speed × time when the
  distance field is missing).

:meth:`TractorSensors.readings` returns a frozen :class:`TractorReadings`: per signal a
:class:`SignalReading` with the value, its receive time (node time), why it is unavailable, and
whether it is stale (no frame for longer than the signal's ``stale_after_s``). A value is never NaN:

* "not available" / "error indicator" fields of the decoder, and figures of merit ERROR or
  NOT_AVAILABLE, give ``value = None`` with that reason (DEGRADED values are used; counted);
* a jump beyond the physical rate bound (:class:`Plausibility`) since the last accepted value,
  ``|v - v_last| > rate · (t - t_last) + slack``, gives ``None`` with reason "implausible jump";
  the bound grows with the time since the last accepted value, so a real step is accepted after
  ``step / rate`` seconds and a single spike is dropped. That time is the node times' difference, or
  the frames' bus timestamps' when larger: frames that waited in the bus while the host stalled are
  all taken at one node time, and judged by their real spacing (:meth:`_Slot.elapsed_s`).

Idle cost (50-100 Hz frames): per frame one identifier decode, one codec decode (memoised for
repeated bytes) and a few float updates under a lock; no other allocation, no logging. The
snapshot is built only when asked for.

Units: SI (rad, rad/s, m, m/s, s). Signs as the messages: roll + right side down, pitch + nose
up (SAE J670), row offset + to the left (the hitch frame's x).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import can

from bridge.isobus.codec import CodecError, decode_frame
from bridge.isobus.j1939 import (
    CYLINDER_ECU_ADDRESS,
    PGN_REAR_HITCH_STATUS,
    PGN_WHEEL_BASED_SPEED,
    TRACTOR_ECU_ADDRESS,
    decode_id,
)
from bridge.isobus.messages import (
    GROUND_AHEAD_SENSOR_ADDRESS,
    GROUND_SENSOR_ADDRESS,
    PGN_GROUND_DISTANCE,
    PGN_ROW_GUIDANCE,
    PGN_SLOPE_SENSOR_INFORMATION,
    PGN_SLOPE_SENSOR_INFORMATION_2,
    ROW_CAMERA_ADDRESS,
    SLOPE_SENSOR_ADDRESS,
    FigureOfMerit,
    GroundDistance,
    RearHitchStatus,
    RowGuidance,
    SlopeSensorInformation,
    SlopeSensorInformation2,
    WheelBasedSpeed,
)
from bridge.link.realtime import ReceivingNode
from bridge.link.state import LinkError, frame_stamp

__all__ = [
    "DISTANCE_WRAP_M",
    "OPTIONAL_SIGNALS",
    "SIGNALS",
    "Plausibility",
    "SignalReading",
    "TractorReadings",
    "TractorSensorCounters",
    "TractorSensors",
    "TractorSensorsConfig",
    "WheelDistance",
]

DISTANCE_WRAP_M = 4_211_081.215
"""The 65096 distance field's range (32 bits at 0.001 m): it wraps here."""
_RESET_STEP_M = 1000.0
"""A distance step this large between two frames is a reset of the sender's odometer, not travel."""

SIGNALS = ("roll", "pitch", "pitch_rate", "ground_distance", "row_offset", "speed", "distance")
OPTIONAL_SIGNALS = ("ground_distance_ahead",)
"""Signals of optional sensors (not in :data:`SIGNALS`: never reported unusable when not fitted)."""
"""The signals of :class:`TractorReadings`, in order."""

_NEVER = "no frame received yet"
_NOT_AVAILABLE = "not available"
_ERROR = "error indicator"
_MERIT_ERROR = "figure of merit: error"
_MERIT_NA = "figure of merit: not available"


def _number(name: str, value: object, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise LinkError(f"{name} must be a number in [{lo:g}, {hi:g}], got {value!r}")
    if not lo <= value <= hi:
        raise LinkError(f"{name} = {value!r} is outside the allowed range [{lo:g}, {hi:g}]")
    return float(value)


@dataclass(frozen=True)
class Plausibility:
    """Physical rate bounds: a change faster than ``rate · Δt + slack`` is an implausible jump.

    Defaults (generous against a tractor's real motion, tight against a sensor fault):

    * attitude 1 rad/s (57 deg/s; a tractor body rolls or pitches at well under 30 deg/s even on
      bumps), slack 0.002 rad (the SSI resolution 35 µrad and the SSI/SSI2 difference);
    * pitch rate 50 rad/s² (a 0.5 rad/s pitch-rate swing in 10 ms), slack 0.01 rad/s;
    * ground distance 5 m/s (hitch lift plus terrain at field speed), slack 0.01 m;
    * row offset 2 m/s (the row's lateral speed relative to the implement), slack 0.05 m (camera
      noise: 10 times the twin's 5 mm RMS);
    * speed 10 m/s² (about 1 g: harder braking than a tractor manages), slack 0.05 m/s.
    """

    attitude_rate_rad_s: float = 1.0
    attitude_slack_rad: float = 0.002
    pitch_accel_rad_s2: float = 50.0
    pitch_rate_slack_rad_s: float = 0.01
    ground_rate_m_s: float = 5.0
    ground_slack_m: float = 0.01
    row_rate_m_s: float = 2.0
    row_slack_m: float = 0.05
    speed_accel_m_s2: float = 10.0
    speed_slack_m_s: float = 0.05

    def __post_init__(self) -> None:
        for name, hi in (
            ("attitude_rate_rad_s", 100.0),
            ("attitude_slack_rad", 1.0),
            ("pitch_accel_rad_s2", 10_000.0),
            ("pitch_rate_slack_rad_s", 10.0),
            ("ground_rate_m_s", 1000.0),
            ("ground_slack_m", 10.0),
            ("row_rate_m_s", 1000.0),
            ("row_slack_m", 10.0),
            ("speed_accel_m_s2", 1000.0),
            ("speed_slack_m_s", 100.0),
        ):
            _number(name, getattr(self, name), 0.0, hi)


@dataclass(frozen=True)
class TractorSensorsConfig:
    """Sources (None: any sender), stale limits [s] and plausibility bounds.

    Attributes:
        slope_source, ground_source, row_source, wheel_source: accepted senders (defaults: the
            project's addresses 226, 227, 228 and the tractor ECU 240).
        ground_ahead_source: the sender of the look-ahead ground sensor's 0xFF26 (default 230; None:
            no look-ahead sensor). Its frames go to ``ground_distance_ahead`` (stale after
            ``ground_stale_after_s``, the ground distance's plausibility), never to ``ground_distance``.
        slope_stale_after_s: SSI/SSI2 (10 ms period) stale after 0.1 s;
        ground_stale_after_s: 0xFF26 (20 ms) after 0.2 s; row_stale_after_s: 0xFF27 (100 ms) after
        0.5 s; wheel_stale_after_s: 65096 (100 ms) after 1 s (as ``WheelOdometer``).
        plausibility: the rate bounds.
        read_draft: also decode the measured draft (RearDraft) of the ISO 11783-7 rear hitch status
            (PGN 65093) from ``hitch_source`` (default the cylinder ECU, 169), stale after
            ``draft_stale_after_s`` (0.3 s); read with :meth:`TractorSensors.draft`. Off by default
            (those frames are then ignored, as before). The draft has no rate bound here: its
            plausibility is the work controller's to judge.
    """

    slope_source: int | None = SLOPE_SENSOR_ADDRESS
    ground_source: int | None = GROUND_SENSOR_ADDRESS
    ground_ahead_source: int | None = GROUND_AHEAD_SENSOR_ADDRESS
    row_source: int | None = ROW_CAMERA_ADDRESS
    wheel_source: int | None = TRACTOR_ECU_ADDRESS
    slope_stale_after_s: float = 0.1
    ground_stale_after_s: float = 0.2
    row_stale_after_s: float = 0.5
    wheel_stale_after_s: float = 1.0
    plausibility: Plausibility = field(default_factory=Plausibility)
    read_draft: bool = False
    hitch_source: int | None = CYLINDER_ECU_ADDRESS
    draft_stale_after_s: float = 0.3

    def __post_init__(self) -> None:
        if not isinstance(self.read_draft, bool):
            raise LinkError(f"read_draft must be True or False, got {self.read_draft!r}")
        h = self.hitch_source
        if h is not None and (isinstance(h, bool) or not isinstance(h, int) or not 0 <= h <= 253):
            raise LinkError(f"hitch_source must be None (any sender) or a source address in [0, 253], got {h!r}")
        _number("draft_stale_after_s", self.draft_stale_after_s, 0.01, 60.0)
        for name in ("slope_source", "ground_source", "ground_ahead_source", "row_source", "wheel_source"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 253):
                raise LinkError(f"{name} must be None (any sender) or a source address in [0, 253], got {v!r}")
        for name in ("slope_stale_after_s", "ground_stale_after_s", "row_stale_after_s", "wheel_stale_after_s"):
            _number(name, getattr(self, name), 0.01, 60.0)
        if not isinstance(self.plausibility, Plausibility):
            raise LinkError(f"plausibility must be a Plausibility, got {type(self.plausibility).__name__}")


@dataclass(frozen=True)
class SignalReading:
    """One signal in a snapshot.

    Attributes:
        value: the latest accepted value (SI), or None when the latest frame did not give one.
        received_s: node time of the latest frame about this signal (None: never).
        reason: why ``value`` is None (None when it is a number).
        stale: no frame for longer than the signal's stale limit at the snapshot time (or never).
    """

    value: float | None
    received_s: float | None
    reason: str | None
    stale: bool

    @property
    def usable(self) -> bool:
        """A number, not stale."""
        return self.value is not None and not self.stale

    def age_s(self, now_s: float) -> float | None:
        """Seconds since the latest frame, None if never received."""
        return None if self.received_s is None else now_s - self.received_s

    def fresh(self, now_s: float, max_age_s: float) -> bool:
        """A number received at most ``max_age_s`` before ``now_s``."""
        return self.value is not None and self.received_s is not None and now_s - self.received_s <= max_age_s


@dataclass(frozen=True)
class TractorReadings:
    """The tractor's sensors at ``now_s`` (node time): one :class:`SignalReading` per :data:`SIGNALS`.

    ``distance`` is the distance travelled since the node started (None before the first 65096 frame).
    ``slope_latency_s`` is the latency the slope sensor reports (its angles are that much older).
    """

    now_s: float
    roll: SignalReading
    pitch: SignalReading
    pitch_rate: SignalReading
    ground_distance: SignalReading
    row_offset: SignalReading
    speed: SignalReading
    distance: SignalReading
    slope_latency_s: float | None = None
    ground_distance_ahead: SignalReading = SignalReading(None, None, _NEVER, True)
    """The look-ahead ground sensor (0xFF26 from ``ground_ahead_source``), an optional signal."""

    def signal(self, name: str) -> SignalReading:
        if name not in SIGNALS + OPTIONAL_SIGNALS:
            raise LinkError(f"signal must be one of {', '.join(SIGNALS + OPTIONAL_SIGNALS)}, got {name!r}")
        reading: SignalReading = getattr(self, name)
        return reading

    def fresh(self, now_s: float, max_age_s: float, signals: tuple[str, ...] = SIGNALS) -> bool:
        """Every one of ``signals`` is a number received at most ``max_age_s`` before ``now_s``."""
        return all(self.signal(n).fresh(now_s, max_age_s) for n in signals)

    def unusable(self) -> dict[str, str]:
        """Signals that are not usable at the snapshot time, with the reason."""
        out = {}
        for n in SIGNALS:
            r = self.signal(n)
            if r.value is None:
                out[n] = r.reason or _NOT_AVAILABLE
            elif r.stale:
                out[n] = f"stale: last frame {r.age_s(self.now_s):.3f} s ago"
        return out


@dataclass(frozen=True)
class TractorSensorCounters:
    """Counts since start.

    ``frames``: frames of the sensor messages from the accepted senders; ``errors``: of those,
    frames the codec rejected (wrong DLC, reserved values); ``unavailable``: signal values the
    frame marked not available / error (or by the figure of merit); ``implausible``: values
    refused as jumps; ``degraded``: values used with figure of merit DEGRADED; ``ignored``: other
    frames (other PGNs, other senders, standard ids, error frames).
    """

    frames: int = 0
    errors: int = 0
    unavailable: int = 0
    implausible: int = 0
    degraded: int = 0
    ignored: int = 0


class _Slot:
    """The latest state of one signal (mutable, preallocated: no allocation per frame).

    ``rate`` None: no rate bound (every finite value is taken)."""

    __slots__ = (
        "value",
        "received_s",
        "reason",
        "good",
        "good_s",
        "good_stamp_s",
        "rate",
        "slack",
        "jump_reason",
        "stale_after_s",
    )

    def __init__(self, rate: float | None, slack: float, unit: str, stale_after_s: float) -> None:
        self.value: float | None = None
        self.received_s: float | None = None
        self.reason: str | None = _NEVER
        self.good = 0.0
        self.good_s: float | None = None
        self.good_stamp_s = 0.0  # the accepted value's frame timestamp (0: the bus gave none)
        self.rate, self.slack, self.stale_after_s = rate, slack, stale_after_s
        self.jump_reason = "" if rate is None else f"implausible jump (faster than {rate:g} {unit} + {slack:g})"

    def elapsed_s(self, now_s: float, stamp_s: float) -> float:
        """The time since the accepted value: the node times' difference, or the frames' own timestamps'
        when larger (frames that waited in the bus during a stall are all taken at one node time;
        their timestamps keep their real spacing), believed up to ``stale_after_s`` beyond the node
        times' difference (a longer gap is a stale signal anyway; a foreign clock cannot open the bound)."""
        dt = 0.0 if self.good_s is None else max(0.0, now_s - self.good_s)
        if stamp_s > 0.0 and self.good_stamp_s > 0.0:
            gap = stamp_s - self.good_stamp_s
            if gap > dt:
                dt = min(gap, dt + self.stale_after_s)
        return dt

    def reading(self, now_s: float) -> SignalReading:
        r = self.received_s
        return SignalReading(self.value, r, self.reason, r is None or now_s - r > self.stale_after_s)


class WheelDistance:
    """Distance travelled [m] from successive PGN 65096 fields (the odometer's accumulation).

    The distance field's increments modulo :data:`DISTANCE_WRAP_M` (a step of 1000 m or more is a
    reset of the sender's odometer, not travel); when the field is missing, the trapezoid of the
    speeds over the time between frames.
    """

    __slots__ = ("total_m", "_last_field", "last_t", "_last_speed")

    def __init__(self) -> None:
        self.total_m = 0.0
        self._last_field: float | None = None
        self.last_t: float | None = None
        """Time of the last frame taken (None: none yet)."""
        self._last_speed: float | None = None

    def add(self, distance_m: float | None, speed_m_s: float | None, now_s: float) -> None:
        """Take one frame's distance field and speed (either may be None) at ``now_s``."""
        if distance_m is not None:
            if self._last_field is not None:
                step = (distance_m - self._last_field) % DISTANCE_WRAP_M
                if step < _RESET_STEP_M:
                    self.total_m += step
            self._last_field = distance_m
        elif speed_m_s is not None and self.last_t is not None and self._last_speed is not None:
            self.total_m += 0.5 * (speed_m_s + self._last_speed) * max(0.0, now_s - self.last_t)
        self._last_speed = speed_m_s
        self.last_t = now_s


class TractorSensors(ReceivingNode):
    """The tractor's sensor messages on ``bus`` into a latest snapshot (module docstring).

    Thread-safe: the runner's thread feeds frames, any thread calls :meth:`readings`,
    :meth:`distance_m` or :meth:`counters`.
    """

    def __init__(self, bus: can.BusABC, config: TractorSensorsConfig | None = None) -> None:
        c = TractorSensorsConfig() if config is None else config
        if not isinstance(c, TractorSensorsConfig):
            raise LinkError(f"config must be a TractorSensorsConfig, got {type(c).__name__}")
        self._bus = bus
        self.config = c
        p = c.plausibility
        self._lock = threading.Lock()
        self._roll = _Slot(p.attitude_rate_rad_s, p.attitude_slack_rad, "rad/s", c.slope_stale_after_s)
        self._pitch = _Slot(p.attitude_rate_rad_s, p.attitude_slack_rad, "rad/s", c.slope_stale_after_s)
        self._rate = _Slot(p.pitch_accel_rad_s2, p.pitch_rate_slack_rad_s, "rad/s²", c.slope_stale_after_s)
        self._ground = _Slot(p.ground_rate_m_s, p.ground_slack_m, "m/s", c.ground_stale_after_s)
        self._ground_ahead = _Slot(p.ground_rate_m_s, p.ground_slack_m, "m/s", c.ground_stale_after_s)
        self._row = _Slot(p.row_rate_m_s, p.row_slack_m, "m/s", c.row_stale_after_s)
        self._speed = _Slot(p.speed_accel_m_s2, p.speed_slack_m_s, "m/s²", c.wheel_stale_after_s)
        self._wheel = WheelDistance()
        self._draft = _Slot(None, 0.0, "N/s", c.draft_stale_after_s)  # no rate bound (config docstring)
        self._latency: float | None = None
        self._sources = {
            PGN_SLOPE_SENSOR_INFORMATION: c.slope_source,
            PGN_SLOPE_SENSOR_INFORMATION_2: c.slope_source,
            PGN_GROUND_DISTANCE: c.ground_source,
            PGN_ROW_GUIDANCE: c.row_source,
            PGN_WHEEL_BASED_SPEED: c.wheel_source,
        }
        if c.read_draft:
            self._sources[PGN_REAR_HITCH_STATUS] = c.hitch_source
        self._now = 0.0
        self._stamp = 0.0  # the frame being taken: its bus timestamp (0: none)
        self._frames = self._errors = self._unavailable = self._implausible = self._degraded = self._ignored = 0

    # -- BusNode (ReceivingNode: bus, start, poll, handle, next_due_s) ---------------------------
    def take(self, frame: can.Message, now_s: float) -> bool:
        """Take one frame at ``now_s``; True if it was a sensor frame we decoded."""
        self._now = now_s
        if not frame.is_extended_id or frame.is_error_frame or frame.is_remote_frame:
            self._ignored += 1
            return False
        try:
            ident = decode_id(frame.arbitration_id)
        except ValueError:
            self._ignored += 1
            return False
        pgn = ident.pgn
        if pgn not in self._sources:
            self._ignored += 1
            return False
        want = self._sources[pgn]
        ahead = (
            pgn == PGN_GROUND_DISTANCE
            and self.config.ground_ahead_source is not None
            and ident.source_address == self.config.ground_ahead_source
        )
        if want is not None and ident.source_address != want and not ahead:
            self._ignored += 1
            return False
        with self._lock:
            self._frames += 1
            self._stamp = frame_stamp(frame) or 0.0
            try:
                d = decode_frame(frame)
            except CodecError:
                self._errors += 1
                return False
            p = d.payload
            if isinstance(p, SlopeSensorInformation):
                self._angle(self._pitch, p.pitch_rad, p.pitch_merit, d.errors, "SsiPitchAngle", now_s)
                self._angle(self._roll, p.roll_rad, p.roll_merit, d.errors, "SsiRollAngle", now_s)
                self._angle(self._rate, p.pitch_rate_rad_s, p.pitch_rate_merit, d.errors, "SsiPitchRate", now_s)
                self._latency = p.latency_s
            elif isinstance(p, SlopeSensorInformation2):
                self._angle(self._pitch, p.pitch_rad, p.pitch_merit, d.errors, "Ssi2PitchAngle", now_s)
                self._angle(self._roll, p.roll_rad, p.roll_merit, d.errors, "Ssi2RollAngle", now_s)
                self._latency = p.latency_s
            elif isinstance(p, GroundDistance):
                slot = self._ground_ahead if ahead else self._ground
                self._angle(slot, p.distance_m, p.merit, d.errors, "GroundDistance", now_s)
            elif isinstance(p, RowGuidance):
                self._angle(self._row, p.offset_m, p.merit, d.errors, "RowLateralOffset", now_s)
            elif isinstance(p, WheelBasedSpeed):
                self._wheel.add(p.distance_m, p.speed_m_s, now_s)
                missing = _ERROR if "WheelBasedMachineSpeed" in d.errors else _NOT_AVAILABLE
                self._update(self._speed, p.speed_m_s, missing, now_s)
            elif isinstance(p, RearHitchStatus):
                self._update(self._draft, p.draft_n, _ERROR if "RearDraft" in d.errors else _NOT_AVAILABLE, now_s)
            else:  # pragma: no cover - the PGN table and the codec agree
                return False
        return True

    def _angle(
        self,
        slot: _Slot,
        value: float | None,
        merit: FigureOfMerit,
        errors: tuple[str, ...],
        signal: str,
        now_s: float,
    ) -> None:
        """A value with its figure of merit: ERROR drops it, then the decoder's None, then NOT_AVAILABLE."""
        if merit is FigureOfMerit.ERROR:
            self._update(slot, None, _MERIT_ERROR, now_s)
        elif value is None:
            self._update(slot, None, _ERROR if signal in errors else _NOT_AVAILABLE, now_s)
        elif merit is FigureOfMerit.NOT_AVAILABLE:
            self._update(slot, None, _MERIT_NA, now_s)
        else:
            if merit is FigureOfMerit.DEGRADED:
                self._degraded += 1
            self._update(slot, value, None, now_s)

    def _update(self, slot: _Slot, value: float | None, missing: str | None, now_s: float) -> None:
        slot.received_s = now_s
        if value is None:
            slot.value, slot.reason = None, missing
            self._unavailable += 1
            return
        stamp = self._stamp
        if (
            slot.rate is not None
            and slot.good_s is not None
            and abs(value - slot.good) > slot.rate * slot.elapsed_s(now_s, stamp) + slot.slack
        ):
            slot.value, slot.reason = None, slot.jump_reason
            self._implausible += 1
            return
        slot.value = slot.good = value
        slot.good_s, slot.good_stamp_s = now_s, stamp
        slot.reason = None

    # -- snapshot --------------------------------------------------------------------------
    @property
    def now_s(self) -> float:
        """The node time of the last poll or frame."""
        return self._now

    def readings(self, now_s: float | None = None) -> TractorReadings:
        """The latest values; staleness judged at ``now_s`` (default: the last poll or frame)."""
        with self._lock:
            t = self._now if now_s is None else now_s
            w = self._wheel
            if w.last_t is None:
                distance = SignalReading(None, None, _NEVER, True)
            else:
                distance = SignalReading(w.total_m, w.last_t, None, t - w.last_t > self.config.wheel_stale_after_s)
            return TractorReadings(
                now_s=t,
                roll=self._roll.reading(t),
                pitch=self._pitch.reading(t),
                pitch_rate=self._rate.reading(t),
                ground_distance=self._ground.reading(t),
                row_offset=self._row.reading(t),
                speed=self._speed.reading(t),
                distance=distance,
                slope_latency_s=self._latency,
                ground_distance_ahead=self._ground_ahead.reading(t),
            )

    def draft(self, now_s: float | None = None) -> SignalReading:
        """The measured draft [N] of the rear hitch status (``read_draft``), staleness judged at ``now_s``."""
        with self._lock:
            return self._draft.reading(self._now if now_s is None else now_s)

    def distance_m(self) -> float | None:
        """Metres travelled since start; None before the first 65096 frame or when it is stale
        (the :meth:`bridge.service.odometer.WheelOdometer.distance_m` contract)."""
        with self._lock:
            last = self._wheel.last_t
            if last is None or self._now - last > self.config.wheel_stale_after_s:
                return None
            return self._wheel.total_m

    def counters(self) -> TractorSensorCounters:
        with self._lock:
            return TractorSensorCounters(
                self._frames, self._errors, self._unavailable, self._implausible, self._degraded, self._ignored
            )
