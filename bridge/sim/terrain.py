"""The terrain twin: ground under a tractor driving along a field, and what its sensors see.

Pure, deterministic values of time (and of the implement's sensor position where needed): no
clock, no bus, no state. :mod:`bridge.sim.sensors` turns them into CAN payloads and
:mod:`bridge.sim.scenario` builds them from TOML files.

World frame: ``s`` distance along the travel direction [m] (+ forward), ``u`` lateral [m] (+ to
the driver's left, the hitch frame's x), ``z`` up [m]. The ground is a height field
``h(s, u) = z(s) + u·tan(c(s))``: a longitudinal profile ``z(s)`` and a cross slope ``c(s)``
[rad] (+ = left side higher, i.e. the tractor rolls right side down). Terrain is spatial: a
wavelength λ driven at speed v is a frequency v/λ (side slopes at 0.02-0.2 Hz at 8 km/h are
wavelengths of 111-11 m).

Tractor on four contact points (closed form). The wheels touch the ground at the rear axle
``s_r`` (the distance travelled) and the front axle ``s_r + L`` (wheelbase L), at ``u = ±T/2``
(track T); heights ``z_rl, z_rr, z_fl, z_fr``. Contacts are taken at their nominal horizontal
positions (the footprint shortens by L·(1 - cos pitch), 0.5 % of L at 0.1 rad: negligible against
wavelengths of metres). The body's contact plane ``z = z0 + b·(s - s_r) + c·u`` is

* ``suspension="rigid"`` (rigid axles, four equally stiff tyres, centred load): the static
  equilibrium of a rigid body on four equal linear springs balances the moments of the tyre
  deflections, which are the normal equations of the least-squares plane through the four
  contacts. For a rectangle they have the closed form
  ``b = ((z_fl + z_fr) - (z_rl + z_rr)) / (2L)``, ``c = ((z_rl + z_fl) - (z_rr + z_fr)) / (2T)``,
  ``z0 = mean(z) - b·L/2``.
* ``suspension="oscillating"`` (the front axle swings about a longitudinal pivot, as
  :mod:`planner.limits.tractor` models the support): the rear axle sets the roll,
  ``c = (z_rl - z_rr) / T``, the pivot (mean front height) the pitch,
  ``b = ((z_fl + z_fr) - (z_rl + z_rr)) / (2L)``, ``z0 = (z_rl + z_rr) / 2``.

Body angles (SAE J670 Euler angles with yaw 0, the slope sensor's convention): the body x axis
is the plane's direction along the travel, x_b ∝ (1, 0, b); z_b is the plane normal ∝ (-b, -c, 1).
Then ``pitch = atan(b)`` (+ nose up) and ``roll = asin(c / sqrt(1 + b² + c²))`` (+ right side
down); on a pure side slope roll = atan(c), on a pure grade pitch = atan(b).

Implement ground. :meth:`TerrainTwin.implement_ground_z` is the ground's height above the
tractor's contact plane at a point ``behind`` metres behind the rear axle and ``lateral`` metres
to the left, measured along the world vertical (relative to the body normal the error is a factor
cos(angle), 0.5 % of the deviation at 0.1 rad). A ground-distance sensor at height ``H`` above the
contact plane at that point (the hitch pose gives ``H``) reads ``H - implement_ground_z``.

Crop row. The row's lateral position under the implement is a band-limited function of the
distance (a sum of ``n`` sines with log-spaced wavelengths in a band and seeded random phases,
amplitudes set so the RMS is ``rms``); the camera adds white noise of ``noise_rms`` per sample
and updates at ``rate_hz`` (sample and hold). The camera sees the row ``camera_ahead_m`` ahead of
the implement (0: under it; a camera on the tractor's front axle gives a preview). Everything is
seeded and deterministic.

Look-ahead ground sensor (:class:`LookAheadGroundSensor`). A ground-distance sensor on the tractor's
body ``ahead_m`` ahead of the implement's ground point (e.g. on the front weight, ahead of the front
axle) at a fixed height ``mount_height_m`` above the contact plane at its point: it moves with the
body (pitch and heave), so it reads ``mount_height_m − (ground above the contact plane there)`` plus
white noise of ``noise_rms_m`` per sample (a pure function of the seed and the time in ms). It gives
a terrain-following client a preview of the ground ``ahead_m`` before the implement reaches it.
"""

from __future__ import annotations

import bisect
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, Protocol

import numpy as np

from planner.errors import HitchInputError

if TYPE_CHECKING:
    from planner.limits.tractor import Tractor

__all__ = [
    "BodyAttitude",
    "CrossSlopeWave",
    "GroundProfile",
    "LookAheadGroundSensor",
    "RowSignal",
    "SampledGround",
    "SineGround",
    "SpeedProfile",
    "Suspension",
    "TerrainError",
    "TerrainTwin",
    "TractorGeometry",
    "TractorState",
    "Undulation",
    "body_attitude",
    "contact_plane",
]

Suspension = Literal["rigid", "oscillating"]


class TerrainError(HitchInputError):
    """A terrain, tractor, speed or signal value out of its range (named in the message)."""


def _number(name: str, value: object, lo: float, hi: float, *, open_lo: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TerrainError(f"{name} must be a number, got {value!r}")
    v = float(value)
    bad_lo = v <= lo if open_lo else v < lo
    if not math.isfinite(v) or bad_lo or v > hi:
        raise TerrainError(f"{name} = {value!r} is outside the allowed range {'(' if open_lo else '['}{lo:g}, {hi:g}]")
    return v


# --- ground profiles ------------------------------------------------------------------------


class GroundProfile(Protocol):
    """A ground height field: longitudinal profile z(s) [m] and cross slope c(s) [rad]."""

    def profile_m(self, s: float) -> float:
        """Ground height on the travel line at distance ``s`` [m]."""
        ...

    def cross_slope_rad(self, s: float) -> float:
        """Cross slope at distance ``s`` [rad], + left side higher."""
        ...


def _height(ground: GroundProfile, s: float, u: float) -> float:
    return ground.profile_m(s) + u * math.tan(ground.cross_slope_rad(s))


@dataclass(frozen=True)
class Undulation:
    """One sine of the longitudinal profile: ``amplitude_m · sin(2π s / wavelength_m + phase_rad)``."""

    amplitude_m: float
    wavelength_m: float
    phase_rad: float = 0.0

    def __post_init__(self) -> None:
        _number("amplitude_m", self.amplitude_m, -1.0, 1.0)
        _number("wavelength_m", self.wavelength_m, 0.5, 10_000.0)
        _number("phase_rad", self.phase_rad, -10.0, 10.0)

    def at(self, s: float) -> float:
        return self.amplitude_m * math.sin(2.0 * math.pi * s / self.wavelength_m + self.phase_rad)


@dataclass(frozen=True)
class CrossSlopeWave:
    """One sine of the cross slope: ``amplitude_rad · sin(2π s / wavelength_m + phase_rad)``."""

    amplitude_rad: float
    wavelength_m: float
    phase_rad: float = 0.0

    def __post_init__(self) -> None:
        _number("amplitude_rad", self.amplitude_rad, -0.5, 0.5)
        _number("wavelength_m", self.wavelength_m, 0.5, 10_000.0)
        _number("phase_rad", self.phase_rad, -10.0, 10.0)

    def at(self, s: float) -> float:
        return self.amplitude_rad * math.sin(2.0 * math.pi * s / self.wavelength_m + self.phase_rad)


@dataclass(frozen=True)
class SineGround:
    """Constant grade and cross slope plus sums of sines.

    ``z(s) = s·tan(grade_rad) + Σ undulations``, ``c(s) = cross_slope_rad + Σ cross_waves``.
    """

    grade_rad: float = 0.0
    cross_slope_rad_0: float = 0.0
    undulations: tuple[Undulation, ...] = ()
    cross_waves: tuple[CrossSlopeWave, ...] = ()

    def __post_init__(self) -> None:
        _number("grade_rad", self.grade_rad, -0.5, 0.5)
        _number("cross_slope_rad", self.cross_slope_rad_0, -0.5, 0.5)
        peak = abs(self.cross_slope_rad_0) + sum(abs(w.amplitude_rad) for w in self.cross_waves)
        if peak > 0.5:
            raise TerrainError(
                f"cross slope peaks at {peak:g} rad: constant + wave amplitudes must stay within 0.5 rad"
            )

    def profile_m(self, s: float) -> float:
        return s * math.tan(self.grade_rad) + sum(w.at(s) for w in self.undulations)

    def cross_slope_rad(self, s: float) -> float:
        return self.cross_slope_rad_0 + sum(w.at(s) for w in self.cross_waves)


@dataclass(frozen=True)
class SampledGround:
    """A sampled profile: heights (and cross slopes) at increasing distances, linearly interpolated.

    Before the first and after the last sample the end values hold.
    """

    distances_m: tuple[float, ...]
    heights_m: tuple[float, ...]
    cross_slopes_rad: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        n = len(self.distances_m)
        if n < 2:
            raise TerrainError(f"a sampled profile needs at least 2 samples, got {n}")
        if len(self.heights_m) != n or (self.cross_slopes_rad is not None and len(self.cross_slopes_rad) != n):
            raise TerrainError("distances, heights and cross slopes of a sampled profile must have equal lengths")
        for i in range(n):
            _number(f"distance_m[{i}]", self.distances_m[i], -1e6, 1e6)
            _number(f"height_m[{i}]", self.heights_m[i], -100.0, 100.0)
            if self.cross_slopes_rad is not None:
                _number(f"cross_slope_rad[{i}]", self.cross_slopes_rad[i], -0.5, 0.5)
            if i and not self.distances_m[i] > self.distances_m[i - 1]:
                raise TerrainError(f"distance_m[{i}] = {self.distances_m[i]} must exceed the previous sample")

    def _interp(self, values: Sequence[float], s: float) -> float:
        d = self.distances_m
        if s <= d[0]:
            return values[0]
        if s >= d[-1]:
            return values[-1]
        i = bisect.bisect_right(d, s)
        w = (s - d[i - 1]) / (d[i] - d[i - 1])
        return values[i - 1] + w * (values[i] - values[i - 1])

    def profile_m(self, s: float) -> float:
        return self._interp(self.heights_m, s)

    def cross_slope_rad(self, s: float) -> float:
        return 0.0 if self.cross_slopes_rad is None else self._interp(self.cross_slopes_rad, s)


# --- speed -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class SpeedProfile:
    """Ground speed [m/s] piecewise linear in time through ``(times_s[i], speeds_m_s[i])``.

    Before the first time the first speed holds, after the last the last one; the distance is
    the exact integral (trapezoids). ``SpeedProfile.constant(v)`` drives at ``v`` from t = 0.
    """

    times_s: tuple[float, ...]
    speeds_m_s: tuple[float, ...]

    def __post_init__(self) -> None:
        n = len(self.times_s)
        if n < 1 or len(self.speeds_m_s) != n:
            raise TerrainError(
                "a speed profile needs at least one (time, speed) pair, times and speeds equal in number"
            )
        for i in range(n):
            _number(f"time_s[{i}]", self.times_s[i], 0.0, 1e6)
            _number(f"speed_m_s[{i}]", self.speeds_m_s[i], 0.0, 15.0)
            if i and not self.times_s[i] > self.times_s[i - 1]:
                raise TerrainError(f"time_s[{i}] = {self.times_s[i]} must exceed the previous sample")

    @classmethod
    def constant(cls, speed_m_s: float) -> SpeedProfile:
        return cls((0.0,), (speed_m_s,))

    def speed_m_s(self, t: float) -> float:
        ts, vs = self.times_s, self.speeds_m_s
        if t <= ts[0]:
            return vs[0]
        if t >= ts[-1]:
            return vs[-1]
        i = bisect.bisect_right(ts, t)
        w = (t - ts[i - 1]) / (ts[i] - ts[i - 1])
        return vs[i - 1] + w * (vs[i] - vs[i - 1])

    def distance_m(self, t: float) -> float:
        """Distance travelled from t = 0 to ``t`` (t >= 0) [m]."""
        if t <= 0.0:
            return 0.0
        ts = self.times_s
        total, prev_t, prev_v = 0.0, 0.0, self.speed_m_s(0.0)
        for ti in ts:
            if ti <= prev_t:
                continue
            if ti >= t:
                break
            vi = self.speed_m_s(ti)
            total += 0.5 * (prev_v + vi) * (ti - prev_t)
            prev_t, prev_v = ti, vi
        return total + 0.5 * (prev_v + self.speed_m_s(t)) * (t - prev_t)


# --- tractor on the ground -------------------------------------------------------------------


@dataclass(frozen=True)
class TractorGeometry:
    """Wheelbase and track [m] (ranges as :class:`planner.limits.tractor.Tractor`) and suspension."""

    wheelbase_m: float = 2.70
    track_m: float = 1.80
    suspension: Suspension = "rigid"

    def __post_init__(self) -> None:
        _number("wheelbase_m", self.wheelbase_m, 0.0, 10.0, open_lo=True)
        _number("track_m", self.track_m, 0.0, 5.0, open_lo=True)
        if self.suspension not in ("rigid", "oscillating"):
            raise TerrainError(f"suspension must be 'rigid' or 'oscillating', got {self.suspension!r}")

    @classmethod
    def from_tractor(cls, tractor: Tractor, suspension: Suspension = "rigid") -> TractorGeometry:
        """From a :class:`planner.limits.tractor.Tractor` (its ``wheelbase`` and ``rear_track``)."""
        return cls(float(tractor.wheelbase), float(tractor.rear_track), suspension)


def contact_plane(
    z_rl: float, z_rr: float, z_fl: float, z_fr: float, geometry: TractorGeometry
) -> tuple[float, float, float]:
    """``(z0, b, c)`` of the contact plane ``z = z0 + b·(s - s_r) + c·u`` (module docstring)."""
    L, T = geometry.wheelbase_m, geometry.track_m
    b = ((z_fl + z_fr) - (z_rl + z_rr)) / (2.0 * L)
    if geometry.suspension == "rigid":
        c = ((z_rl + z_fl) - (z_rr + z_fr)) / (2.0 * T)
        z0 = 0.25 * (z_rl + z_rr + z_fl + z_fr) - 0.5 * b * L
    else:
        c = (z_rl - z_rr) / T
        z0 = 0.5 * (z_rl + z_rr)
    return z0, b, c


@dataclass(frozen=True)
class BodyAttitude:
    """Pitch (+ nose up) and roll (+ right side down) [rad], SAE J670 with yaw 0."""

    pitch_rad: float
    roll_rad: float


def body_attitude(b: float, c: float) -> BodyAttitude:
    """The Euler angles of a body lying on a plane of slopes ``b`` (along s) and ``c`` (along u)."""
    return BodyAttitude(math.atan(b), math.asin(c / math.sqrt(1.0 + b * b + c * c)))


@dataclass(frozen=True)
class TractorState:
    """The tractor at one instant (SI)."""

    t_s: float
    distance_m: float
    """Rear-axle distance along the travel direction (= distance travelled)."""
    speed_m_s: float
    pitch_rad: float
    roll_rad: float
    pitch_rate_rad_s: float
    roll_rate_rad_s: float
    rear_axle_z_m: float
    """World height of the contact plane below the rear-axle centre."""


@dataclass(frozen=True)
class RowSignal:
    """A band-limited crop-row offset of distance and its camera measurement (module docstring).

    Attributes:
        rms_m: RMS of the true row offset [m].
        wavelength_min_m, wavelength_max_m: the band, in wavelengths along the travel [m].
        noise_rms_m: camera noise RMS per sample [m].
        rate_hz: camera update rate [Hz].
        seed: seeds the phases and the noise.
        components: number of sines.
        camera_ahead_m: where along the travel the camera sees the row, ahead of the implement [m]
            (the look-ahead d = camera position − implement position; 0 = a camera under the
            implement, no preview). A camera at the tractor's front axle sees the row
            ``wheelbase_m + implement_behind_m`` ahead (3.9 m for the default tractor): the offset
            seen now is the implement's target d / v seconds later.
    """

    rms_m: float = 0.02
    wavelength_min_m: float = 3.0
    wavelength_max_m: float = 30.0
    noise_rms_m: float = 0.005
    rate_hz: float = 10.0
    seed: int = 0
    components: int = 24
    camera_ahead_m: float = 0.0
    _phases: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _wavenumbers: tuple[float, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        _number("rms_m", self.rms_m, 0.0, 1.0)
        _number("wavelength_min_m", self.wavelength_min_m, 0.1, 1000.0)
        _number("wavelength_max_m", self.wavelength_max_m, self.wavelength_min_m, 1000.0)
        _number("noise_rms_m", self.noise_rms_m, 0.0, 0.5)
        _number("rate_hz", self.rate_hz, 0.1, 100.0)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**63:
            raise TerrainError(f"seed must be an integer in [0, 2^63), got {self.seed!r}")
        if isinstance(self.components, bool) or not isinstance(self.components, int) or not 1 <= self.components <= 256:
            raise TerrainError(f"components must be an integer in [1, 256], got {self.components!r}")
        _number("camera_ahead_m", self.camera_ahead_m, 0.0, 20.0)
        rng = np.random.default_rng([self.seed, 0])
        lam = np.geomspace(self.wavelength_max_m, self.wavelength_min_m, self.components)
        object.__setattr__(self, "_wavenumbers", tuple(float(k) for k in 2.0 * math.pi / lam))
        object.__setattr__(self, "_phases", tuple(float(p) for p in rng.uniform(0.0, 2.0 * math.pi, self.components)))

    def true_offset_m(self, s: float) -> float:
        """The row's lateral offset at distance ``s`` [m], + left."""
        a = self.rms_m * math.sqrt(2.0 / self.components)
        return a * sum(math.sin(k * s + p) for k, p in zip(self._wavenumbers, self._phases, strict=True))

    def sample_index(self, t: float) -> int:
        """The camera sample held at time ``t`` (sample k is taken at k / rate_hz)."""
        return math.floor(t * self.rate_hz + 1e-9)

    def noise_m(self, k: int) -> float:
        """The camera noise of sample ``k`` (a pure function of seed and k)."""
        if self.noise_rms_m == 0.0:
            return 0.0
        return float(np.random.default_rng([self.seed, 1, k]).normal(0.0, self.noise_rms_m))


@dataclass(frozen=True)
class LookAheadGroundSensor:
    """A ground-distance sensor on the tractor's body ahead of the implement (module docstring).

    Attributes:
        ahead_m: distance of its ground point ahead of the implement's ground point [m], [0, 20];
            0 = no such sensor. The tractor's front axle is ``wheelbase_m + implement_behind_m``
            ahead of the implement (3.9 m with the twin's default tractor).
        mount_height_m: its height above the tractor's contact plane at its point [m], [0.1, 3].
        noise_rms_m: white noise per sample [m], [0, 0.05].
        seed: seeds the noise.
    """

    ahead_m: float = 0.0
    mount_height_m: float = 0.8
    noise_rms_m: float = 0.003
    seed: int = 0

    def __post_init__(self) -> None:
        _number("ground_sensor_ahead_m", self.ahead_m, 0.0, 20.0)
        _number("ground_sensor_mount_height_m", self.mount_height_m, 0.1, 3.0)
        _number("ground_sensor_noise_rms_m", self.noise_rms_m, 0.0, 0.05)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**63:
            raise TerrainError(f"seed must be an integer in [0, 2^63), got {self.seed!r}")

    @property
    def fitted(self) -> bool:
        """There is a look-ahead sensor (``ahead_m`` > 0)."""
        return self.ahead_m > 0.0

    def noise_m(self, t: float) -> float:
        """The noise of the sample taken at time ``t`` [s] (a pure function of the seed and t in ms)."""
        if self.noise_rms_m == 0.0:
            return 0.0
        return float(np.random.default_rng([self.seed, 2, round(t * 1000.0)]).normal(0.0, self.noise_rms_m))


@dataclass(frozen=True)
class TerrainTwin:
    """A tractor driving over ground at a speed profile, with a crop row: everything a function of time.

    Attributes:
        ground: the height field.
        speed: ground speed over time.
        tractor: wheelbase, track, suspension.
        row: the crop-row signal.
        implement_behind_m: default distance of the implement's ground point behind the rear axle.
        ground_sensor: the look-ahead ground-distance sensor (default: none fitted).
    """

    ground: GroundProfile = field(default_factory=SineGround)
    speed: SpeedProfile = field(default_factory=lambda: SpeedProfile.constant(0.0))
    tractor: TractorGeometry = field(default_factory=TractorGeometry)
    row: RowSignal = field(default_factory=RowSignal)
    implement_behind_m: float = 1.2
    ground_sensor: LookAheadGroundSensor = field(default_factory=LookAheadGroundSensor)

    _RATE_STEP_S = 1e-3
    """Half-width of the central difference of the attitude rates [s]."""

    def __post_init__(self) -> None:
        _number("implement_behind_m", self.implement_behind_m, 0.0, 10.0)

    def distance_m(self, t: float) -> float:
        return self.speed.distance_m(t)

    def contacts_m(self, t: float) -> tuple[float, float, float, float]:
        """Ground heights under the rear-left, rear-right, front-left, front-right wheels [m]."""
        return self._contacts_at(self.distance_m(t))

    def _contacts_at(self, s: float) -> tuple[float, float, float, float]:
        half, L, g = 0.5 * self.tractor.track_m, self.tractor.wheelbase_m, self.ground
        return (_height(g, s, half), _height(g, s, -half), _height(g, s + L, half), _height(g, s + L, -half))

    def _plane(self, t: float) -> tuple[float, float, float]:
        """The contact plane at ``t``: a function of the distance travelled only, so the last one is kept
        (a tractor standing still, as the service's default twin, computes it once, not 200 times a second)."""
        s = self.distance_m(t)
        last = self.__dict__.get("_last_plane")  # (distance, plane); frozen: kept beside the fields
        if last is not None and last[0] == s:
            return last[1]
        plane = contact_plane(*self._contacts_at(s), self.tractor)
        self.__dict__["_last_plane"] = (s, plane)
        return plane

    def attitude(self, t: float) -> BodyAttitude:
        _, b, c = self._plane(t)
        return body_attitude(b, c)

    @functools.cached_property
    def _planar(self) -> bool:
        """The ground is one plane (a constant grade and cross slope): the attitude never changes."""
        g = self.ground
        return isinstance(g, SineGround) and not g.undulations and not g.cross_waves

    def state(self, t: float) -> TractorState:
        z0, b, c = self._plane(t)
        att = body_attitude(b, c)
        if self._planar:  # constant attitude: its rates are exactly 0 (the central difference of a constant)
            pitch_rate = roll_rate = 0.0
        else:
            h = self._RATE_STEP_S
            before, after = self.attitude(max(0.0, t - h)), self.attitude(t + h)
            dt = t + h - max(0.0, t - h)
            pitch_rate = (after.pitch_rad - before.pitch_rad) / dt
            roll_rate = (after.roll_rad - before.roll_rad) / dt
        return TractorState(
            t_s=t,
            distance_m=self.distance_m(t),
            speed_m_s=self.speed.speed_m_s(t),
            pitch_rad=att.pitch_rad,
            roll_rad=att.roll_rad,
            pitch_rate_rad_s=pitch_rate,
            roll_rate_rad_s=roll_rate,
            rear_axle_z_m=z0,
        )

    def implement_ground_z(self, t: float, *, behind_m: float | None = None, lateral_m: float = 0.0) -> float:
        """Ground height above the tractor's contact plane [m] ``behind_m`` behind the rear axle
        (default :attr:`implement_behind_m`) and ``lateral_m`` to the left (module docstring)."""
        d = self.implement_behind_m if behind_m is None else _number("behind_m", behind_m, 0.0, 10.0)
        u = _number("lateral_m", lateral_m, -5.0, 5.0)
        return self._above_plane(t, -d, u)

    def _above_plane(self, t: float, ahead_of_rear_m: float, lateral_m: float) -> float:
        """Ground height above the contact plane at ``ahead_of_rear_m`` ahead of the rear axle [m]."""
        z0, b, c = self._plane(t)
        s = self.distance_m(t) + ahead_of_rear_m
        return _height(self.ground, s, lateral_m) - (z0 + b * ahead_of_rear_m + c * lateral_m)

    def ground_ahead_z(self, t: float) -> float:
        """Ground height above the contact plane at the look-ahead sensor's point [m] (no noise)."""
        return self._above_plane(t, self.ground_sensor.ahead_m - self.implement_behind_m, 0.0)

    def ground_ahead_distance_m(self, t: float) -> float:
        """What the look-ahead ground sensor reads at ``t`` [m]: its mount height minus the ground
        above the contact plane at its point, plus its noise (:class:`LookAheadGroundSensor`)."""
        g = self.ground_sensor
        return g.mount_height_m - self.ground_ahead_z(t) + g.noise_m(t)

    def ground_distance_m(
        self, t: float, sensor_height_m: float, *, behind_m: float | None = None, lateral_m: float = 0.0
    ) -> float:
        """What a ground-distance sensor ``sensor_height_m`` above the contact plane reads [m]."""
        h = _number("sensor_height_m", sensor_height_m, -5.0, 10.0)
        return h - self.implement_ground_z(t, behind_m=behind_m, lateral_m=lateral_m)

    def row_true_offset_m(self, t: float) -> float:
        """True crop-row offset under the implement at time ``t`` [m], + left."""
        return self.row.true_offset_m(self.distance_m(t) - self.implement_behind_m)

    def row_measured_offset_m(self, t: float) -> float:
        """The camera's reading at ``t``: the sample taken at the last 1/rate_hz tick, with its noise,
        of the row :attr:`RowSignal.camera_ahead_m` ahead of the implement."""
        k = self.row.sample_index(t)
        s = self.distance_m(k / self.row.rate_hz) - self.implement_behind_m + self.row.camera_ahead_m
        return self.row.true_offset_m(s) + self.row.noise_m(k)
