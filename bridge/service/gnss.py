"""The tractor's GNSS position and the field's lines: crossing detection for maneuver ``wait_for: {line: …}``.

**Position** — Zenoh key ``<prefix>/tractor/gnss`` (put, JSON), one fix per message, at any rate
(the twin sends 10 Hz)::

    {"lat": 48.137154, "lon": 11.576124}                  # WGS84 degrees (what a receiver gives)
    {"lat": …, "lon": …, "speed": 3.3, "heading": 1.57}   # optional: ground speed [m/s], course [rad]
    {"east": 12.5, "north": -3.0}                        # or local metres in the tracker's plane

``heading`` is the course over ground, clockwise from north [rad]. Without ``speed``/``heading``
the velocity is taken from the last two fixes. A fix is stamped with the receiving clock (the
control core's); it is stale after ``stale_after_s`` (default 1 s) and a ``wait_for`` line step
then keeps waiting (the maneuver's timeout ends it) — a crossing seen meanwhile still counts.

**Lines** — GeoJSON (RFC 7946: ``[lon, lat]`` in degrees) ``LineString`` geometries, or
``Feature``/``FeatureCollection`` of them (the name from ``properties.name`` when not given):
field boundaries and headland lines, 2–1000 vertices each, at most :data:`MAX_LINES` lines. They are
saved with ``<prefix>/lines/save`` ``{"name": …, "geojson": {…}}`` (``hitch lines save NAME FILE``),
listed with ``lines/list`` and deleted with ``lines/delete``; they live in the control core's memory
(saved again after a restart, e.g. from the file).

**Projection** — a local tangent plane (east, north [m]) at an origin: the first vertex of the first
line saved (or of the first fix if that comes first). ``east = Δλ·N(φ0)·cos φ0``, ``north = Δφ·M(φ0)``
with the WGS84 radii of curvature M (meridian) and N (prime vertical): a few centimetres of distortion
within 2 km of the origin, and fixes and lines share the plane, so a crossing is a crossing.

**Crossing** — each fix's segment from the previous fix is intersected with every line (a crossing
is counted, with the interpolated point); between fixes the position is extrapolated with the
velocity, so :meth:`GnssTracker.approach` gives the distance still to go to the line along the
course at the time asked (the ray from the position along the velocity) and the ground speed —
what lead compensation needs: a step of planned duration T that must be complete at the line
starts when that distance is ``≤ v·T``.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bridge.service.maneuvers.steps import ManeuverSchemaError, check_name
from planner.errors import HitchInputError
from planner.textfile import read_text_file

__all__ = [
    "GnssError",
    "LocalTangentPlane",
    "FieldLine",
    "LineApproach",
    "GnssTracker",
    "parse_lines",
    "MAX_LINES",
    "MAX_VERTICES",
    "TwinGnss",
    "start_twin_gnss",
    "lines_handlers",
    "restore_lines",
]

MAX_LINES = 64
MAX_VERTICES = 1000
#: the farthest a line's vertex may lie from the tangent plane's origin [m] (one field; the plane's
#: distortion stays at decimetres)
MAX_LINE_RADIUS_M = 20_000.0
#: the shortest segment of a line [m]
MIN_SEGMENT_M = 0.01
_A, _F = 6378137.0, 1 / 298.257223563  # WGS84
_E2 = _F * (2 - _F)
_MIN_SPEED = 0.05  # m/s: below this the course is the last one known
#: the fastest a tractor may seem to move between two fixes [m/s] (about 108 km/h): a fix beyond is an outlier,
#: refused, never a line crossing (one 1.5 km jump fired a headland step 148 m early: a field trial)
MAX_FIX_SPEED_M_S = 30.0


class GnssError(HitchInputError):
    """A fix, a line or a setting that cannot be taken; the message names the field and the allowed range."""


def _num(name: str, v: Any, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise GnssError(f"{name} must be a finite number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


@dataclass(frozen=True)
class LocalTangentPlane:
    """East/north metres about an origin (``lat0``, ``lon0`` in degrees); see the module docstring."""

    lat0: float
    lon0: float

    def __post_init__(self) -> None:
        _num("lat0", self.lat0, -85.0, 85.0)
        _num("lon0", self.lon0, -180.0, 180.0)

    @property
    def _radii(self) -> tuple[float, float]:
        s = math.sin(math.radians(self.lat0))
        w = math.sqrt(1 - _E2 * s * s)
        return _A * (1 - _E2) / w**3, _A / w  # M, N

    def to_local(self, lat: float, lon: float) -> tuple[float, float]:
        m, n = self._radii
        dlon = (lon - self.lon0 + 180.0) % 360.0 - 180.0
        return math.radians(dlon) * n * math.cos(math.radians(self.lat0)), math.radians(lat - self.lat0) * m

    def to_geodetic(self, east: float, north: float) -> tuple[float, float]:
        m, n = self._radii
        return self.lat0 + math.degrees(north / m), self.lon0 + math.degrees(
            east / (n * math.cos(math.radians(self.lat0)))
        )


@dataclass(frozen=True)
class FieldLine:
    """A named line: its vertices ``[lon, lat]`` (degrees) as given."""

    name: str
    coordinates: tuple[tuple[float, float], ...]

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "vertices": len(self.coordinates),
            "coordinates": [list(c) for c in self.coordinates],
        }


@dataclass(frozen=True)
class LineApproach:
    """Where the tractor is relative to a line at the time asked.

    ``distance_m``: still to go along the course to the line (None: the course does not meet it, or
    the course is unknown); ``speed_m_s``: ground speed; ``crossings``: how often the line was crossed
    since it was saved."""

    distance_m: float | None
    speed_m_s: float
    crossings: int


def _coords(where: str, raw: Any) -> tuple[tuple[float, float], ...]:
    if not isinstance(raw, list) or not 2 <= len(raw) <= MAX_VERTICES:
        raise GnssError(f"{where}.coordinates must be a list of 2 to {MAX_VERTICES} [lon, lat] positions")
    out = []
    for i, c in enumerate(raw):
        if not isinstance(c, list) or len(c) not in (2, 3):
            raise GnssError(f"{where}.coordinates[{i}] must be [lon, lat] (or [lon, lat, height])")
        lon = _num(f"{where}.coordinates[{i}][0] (lon)", c[0], -180, 180)
        out.append((lon, _num(f"{where}.coordinates[{i}][1] (lat)", c[1], -85, 85)))
        if len(c) == 3:  # a height is allowed (and not used): it must be one
            _num(f"{where}.coordinates[{i}][2] (height, m)", c[2], -1000.0, 10_000.0)
    return tuple(out)


def _check_local(where: str, local: np.ndarray) -> None:
    """A line the tangent plane can carry: every vertex within :data:`MAX_LINE_RADIUS_M` of the origin,
    every segment at least :data:`MIN_SEGMENT_M` long (a repeated vertex has no direction to cross)."""
    r = np.hypot(local[:, 0], local[:, 1])
    far = int(np.argmax(r))
    if r[far] > MAX_LINE_RADIUS_M:
        raise GnssError(
            f"{where}.coordinates[{far}] lies {r[far] / 1000:.1f} km from the plane's origin (the first line vertex "
            f"or GNSS fix the service took); allowed at most {MAX_LINE_RADIUS_M / 1000:g} km: lines of one field, in "
            "[lon, lat] order"
        )
    seg = np.hypot(*np.diff(local, axis=0).T)
    short = int(np.argmin(seg))
    if seg[short] < MIN_SEGMENT_M:
        raise GnssError(
            f"{where}.coordinates[{short}] and [{short + 1}] are {seg[short]:.3g} m apart; a segment must be at "
            f"least {MIN_SEGMENT_M:g} m long (a repeated vertex?)"
        )


def parse_lines(geojson: Any, name: str | None = None) -> list[FieldLine]:
    """The LineStrings of a GeoJSON geometry, Feature or FeatureCollection (see the module docstring).

    ``name`` names a single line (else ``properties.name`` of each feature). Raises :class:`GnssError`.
    """
    if isinstance(geojson, (str, bytes)):
        try:
            geojson = json.loads(geojson)
        except ValueError as exc:
            raise GnssError(f"geojson is not valid JSON: {exc}") from None
    if not isinstance(geojson, Mapping):
        raise GnssError("geojson must be a GeoJSON object (LineString, Feature or FeatureCollection)")
    kind = geojson.get("type")
    features: list[tuple[str, Mapping[str, Any], Any]]
    if kind == "FeatureCollection":
        feats = geojson.get("features")
        if not isinstance(feats, list) or not 1 <= len(feats) <= MAX_LINES:
            raise GnssError(f"geojson.features must be a list of 1 to {MAX_LINES} features")
        features = [(f"geojson.features[{i}]", f, None) for i, f in enumerate(feats)]
    elif kind == "Feature":
        features = [("geojson", geojson, name)]
    elif kind == "LineString":
        features = [("geojson", {"type": "Feature", "geometry": geojson, "properties": {}}, name)]
    else:
        raise GnssError(f"geojson.type must be LineString, Feature or FeatureCollection, got {_type_of(geojson)}")
    out = []
    for where, f, given in features:
        if not isinstance(f, Mapping) or f.get("type") != "Feature":
            raise GnssError(f"{where}.type must be 'Feature'")
        geom, props = f.get("geometry"), f.get("properties") or {}
        if not isinstance(geom, Mapping) or geom.get("type") != "LineString":
            raise GnssError(f"{where}.geometry.type must be 'LineString', got {_type_of(geom)}")
        n = given if given is not None else (props.get("name") if isinstance(props, Mapping) else None)
        if n is None and len(features) == 1:
            n = name
        try:
            n = check_name(n, f"{where}.properties.name (the line name)")
        except ManeuverSchemaError as exc:
            raise GnssError(str(exc)) from None
        out.append(FieldLine(n, _coords(f"{where}.geometry", geom.get("coordinates"))))
    return out


def _type_of(geom: Any) -> str:
    """The ``type`` of a GeoJSON object as a message shows it: its value, "no type" (never Python's None)."""
    if not isinstance(geom, Mapping):
        return f"a {type(geom).__name__}"
    return "no type" if geom.get("type") is None else repr(geom.get("type"))


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def ray_distance(p: np.ndarray, d: np.ndarray, vertices: np.ndarray) -> float | None:
    """Smallest t >= 0 with ``p + t·d`` on the polyline (``d`` a unit vector); None if it misses."""
    best: float | None = None
    for a, b in zip(vertices[:-1], vertices[1:], strict=True):
        e = b - a
        den = _cross(d, e)
        if abs(den) < 1e-12:
            continue
        w = a - p
        t, s = _cross(w, e) / den, _cross(w, d) / den
        if t >= 0.0 and -1e-9 <= s <= 1 + 1e-9 and (best is None or t < best):
            best = t
    return best


def segment_crossing(p0: np.ndarray, p1: np.ndarray, vertices: np.ndarray) -> np.ndarray | None:
    """The first point where the segment ``p0 → p1`` meets the polyline (None: it does not)."""
    d = p1 - p0
    length = float(np.hypot(*d))
    if length < 1e-9:
        return None
    t = ray_distance(p0, d / length, vertices)
    return None if t is None or t > length else p0 + d / length * t


@dataclass
class _Line:
    line: FieldLine
    local: np.ndarray
    crossings: int = 0
    crossed_at: tuple[float, float, float] | None = None  # (t, east, north) of the last crossing


class GnssTracker:
    """The latest fix, the lines and their crossings (see the module docstring). Thread-safe.

    Args:
        clock: the receiving clock [s] (the controller's); fixes are stamped with it.
        stale_after_s: a fix older than this is no position (0.05–60 s).
        origin: (lat, lon) of the tangent plane (None: the first line's first vertex or the first fix).
    """

    def __init__(
        self,
        clock: Callable[[], float],
        *,
        stale_after_s: float = 1.0,
        origin: tuple[float, float] | None = None,
    ):
        self.clock = clock
        self.stale_after_s = _num("stale_after_s", stale_after_s, 0.05, 60.0)
        self.plane = None if origin is None else LocalTangentPlane(*origin)
        self._lock = threading.Lock()
        self._lines: dict[str, _Line] = {}
        self._fix: tuple[float, np.ndarray] | None = None  # (t, position)
        self._velocity: np.ndarray | None = None
        self._course: np.ndarray | None = None  # unit vector of the last known course
        self.fixes = 0
        self.rejected = 0
        self.last_error: str | None = None

    # ------------------------------------------------------------------ lines
    def save_lines(self, geojson: Any, name: str | None = None) -> list[str]:
        """Save (replace) the lines of a GeoJSON object; their names."""
        lines = parse_lines(geojson, name)
        with self._lock:
            if len({**self._lines, **{ln.name: None for ln in lines}}) > MAX_LINES:
                raise GnssError(f"at most {MAX_LINES} lines may be saved (max_lines = {MAX_LINES})")
            plane = self.plane
            if plane is None:
                lon, lat = lines[0].coordinates[0]
                plane = LocalTangentPlane(lat, lon)
            new = {}
            for ln in lines:
                local = np.array([plane.to_local(lat, lon) for lon, lat in ln.coordinates])
                _check_local(f"line {ln.name!r}", local)
                new[ln.name] = _Line(ln, local)
            self.plane = plane  # all or none: a refused save leaves the plane and the lines as they were
            self._lines.update(new)
        return [ln.name for ln in lines]

    def delete_line(self, name: str) -> bool:
        with self._lock:
            return self._lines.pop(name, None) is not None

    def lines(self) -> list[dict[str, Any]]:
        with self._lock:
            return [
                {**ln.line.to_json(), "crossings": ln.crossings, "crossed_at": ln.crossed_at}
                for ln in self._lines.values()
            ]

    def has_line(self, name: str) -> bool:
        with self._lock:
            return name in self._lines

    # ------------------------------------------------------------------ fixes
    def take_payload(self, payload: bytes | str | Mapping[str, Any]) -> bool:
        """A ``tractor/gnss`` message; False (counted in ``rejected``, reason in ``last_error``) if malformed."""
        try:
            data = json.loads(payload) if isinstance(payload, (bytes, str)) else payload
            if not isinstance(data, Mapping):
                raise GnssError("a GNSS fix must be a JSON object")
            self.take_fix(data)
            return True
        except (GnssError, ValueError) as exc:
            self.rejected += 1
            self.last_error = str(exc)[:200]
            return False

    def counts(self) -> dict[str, Any]:
        """``{"fixes", "rejected", "last_rejection"}``: what ``tractor/gnss`` brought (``lines/list`` answers it: a
        bad put is not answered, so a publisher learns here why its fixes do not count)."""
        with self._lock:
            return {"fixes": self.fixes, "rejected": self.rejected, "last_rejection": self.last_error}

    def take_fix(self, data: Mapping[str, Any], now_s: float | None = None) -> None:
        """One fix (``lat``/``lon`` or ``east``/``north``, optional ``speed``, ``heading``); raises GnssError."""
        extra = set(data) - {"lat", "lon", "east", "north", "speed", "heading", "t"}
        if extra:
            raise GnssError(f"unknown key(s) {sorted(extra)} (allowed: lat, lon | east, north; speed, heading, t)")
        now = self.clock() if now_s is None else float(now_s)
        with self._lock:
            if "lat" in data or "lon" in data:
                lat, lon = _num("lat", data.get("lat"), -85, 85), _num("lon", data.get("lon"), -180, 180)
                if self.plane is None:
                    self.plane = LocalTangentPlane(lat, lon)
                p = np.array(self.plane.to_local(lat, lon))
                r = float(np.hypot(*p))
                if r > MAX_LINE_RADIUS_M:  # the lines' plane: a fix of another field, or either in [lat, lon]
                    raise GnssError(
                        f"fix lat {lat:g}, lon {lon:g} lies {r / 1000:.1f} km from the plane's origin (the first line "
                        f"vertex or fix, lat {self.plane.lat0:g}, lon {self.plane.lon0:g}); allowed at most "
                        f"{MAX_LINE_RADIUS_M / 1000:g} km: a fix or the lines in [lat, lon] order, or lines of "
                        "another field?"
                    )
            elif "east" in data or "north" in data:
                p = np.array([_num("east", data.get("east"), -1e5, 1e5), _num("north", data.get("north"), -1e5, 1e5)])
            else:
                raise GnssError("a GNSS fix needs lat and lon [deg] or east and north [m]")
            v = None
            if "speed" in data or "heading" in data:
                sp = _num("speed", data.get("speed"), 0.0, 100.0)
                hd = _num("heading", data.get("heading"), -2 * math.pi, 2 * math.pi)
                v = sp * np.array([math.sin(hd), math.cos(hd)])  # clockwise from north: east = sin, north = cos
            prev = self._fix
            if prev is not None:
                dt = now - prev[0]
                if dt <= self.stale_after_s:  # a jump no tractor makes: an outlier, not a crossing
                    jump = float(np.hypot(*(p - prev[1])))
                    if jump > MAX_FIX_SPEED_M_S * max(dt, 0.0) + 1.0:
                        raise GnssError(
                            f"fix {jump:.1f} m from the last one {dt:.2f} s before (more than "
                            f"{MAX_FIX_SPEED_M_S:g} m/s and 1 m): an outlier, not counted"
                        )
                moved = (p - prev[1]) / dt if dt > 1e-6 else None
                if v is None:
                    v = moved
                elif moved is not None and float(np.hypot(*v)) < _MIN_SPEED <= float(np.hypot(*moved)):
                    v = moved  # the receiver says 0 while its fixes move: the fixes' speed (lead, course)
                if dt <= self.stale_after_s:  # a gap (stale) is no segment: the tractor may have been anywhere
                    for ln in self._lines.values():
                        hit = segment_crossing(prev[1], p, ln.local)
                        if hit is not None:
                            ln.crossings += 1
                            ln.crossed_at = (now, float(hit[0]), float(hit[1]))
            self._fix, self._velocity = (now, p), v
            if v is not None and float(np.hypot(*v)) >= _MIN_SPEED:
                self._course = v / float(np.hypot(*v))
            self.fixes += 1

    def position(self, now_s: float | None = None) -> tuple[float, float] | None:
        """East, north [m] extrapolated to ``now_s`` (None: no fresh fix)."""
        with self._lock:
            st = self._state(self.clock() if now_s is None else now_s)
        return None if st is None else (float(st[0][0]), float(st[0][1]))

    def _state(self, now: float) -> tuple[np.ndarray, float] | None:
        if self._fix is None or now - self._fix[0] > self.stale_after_s:
            return None
        t, p = self._fix
        v = self._velocity if self._velocity is not None else np.zeros(2)
        return p + v * max(0.0, now - t), float(np.hypot(*v))

    def crossings(self, name: str) -> int | None:
        with self._lock:
            ln = self._lines.get(name)
            return None if ln is None else ln.crossings

    def approach(self, name: str, now_s: float) -> LineApproach | None:
        """Distance to go to line ``name`` along the course and the ground speed at ``now_s`` (None: no
        such line, or no fresh fix)."""
        with self._lock:
            ln = self._lines.get(name)
            st = self._state(now_s)
            if ln is None or st is None:
                return None
            p, speed = st
            d = None if self._course is None else ray_distance(p, self._course, ln.local)
            return LineApproach(d, speed, ln.crossings)


# ---------------------------------------------------------------------------------------- the twin's receiver
class TwinGnss:
    """The twin's GNSS receiver: fixes of the simulated tractor at ``distance()`` [m] (its wheel-based
    distance, so GNSS and odometer agree) along a straight course (``heading`` clockwise from north
    [rad]) from ``start`` (lat, lon [deg]); ``speed()`` [m/s]. :meth:`fix` is one ``tractor/gnss``
    message, :meth:`publish_every` puts them from a thread (e.g. on a Zenoh publisher)."""

    def __init__(
        self,
        distance: Callable[[], float | None],
        speed: Callable[[], float],
        *,
        start: tuple[float, float] = (48.0, 11.0),
        heading: float = math.pi / 2,
    ):
        self.distance, self.speed = distance, speed
        self.plane = LocalTangentPlane(*start)
        self.heading = float(heading)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.put_failures = 0
        """Puts that raised (the thread goes on with the next fix; it ends only with :meth:`close`)."""
        self.last_error: str | None = None

    def local(self) -> tuple[float, float] | None:
        d = self.distance()
        if d is None:
            return None
        return d * math.sin(self.heading), d * math.cos(self.heading)

    def fix(self) -> dict[str, Any] | None:
        p = self.local()
        if p is None:
            return None
        lat, lon = self.plane.to_geodetic(*p)
        return {"lat": lat, "lon": lon, "speed": float(self.speed()), "heading": self.heading}

    def publish_every(self, put: Callable[[bytes], Any], period_s: float = 0.1) -> threading.Thread:
        """Put a fix every ``period_s`` (a thread, until :meth:`close`). A put that raises is counted
        (``put_failures``, ``last_error``) and the next fix is put as usual: a receiver does not stop for one lost
        message (it stopped for good on the first one)."""

        def run() -> None:
            while not self._stop.wait(period_s):
                f = self.fix()
                if f is not None and not self._stop.is_set():
                    try:
                        put(json.dumps(f).encode())
                    except Exception as exc:  # noqa: BLE001 — e.g. zenoh.ZError; close() ends the thread
                        self.put_failures += 1
                        self.last_error = f"{type(exc).__name__}: {exc}"

        t = threading.Thread(target=run, name="twin-gnss", daemon=True)
        self._thread = t
        t.start()
        return t

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the thread and wait (up to ``timeout_s``) for a put in progress to end, so whoever
        owns the publisher may undeclare it next (a Zenoh publisher must not be put on and undeclared
        at once: that raised "Already mutably borrowed" in the thread)."""
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout_s)


class _TwinGnssPublisher:
    """A running :class:`TwinGnss` putting on a Zenoh publisher; ``undeclare()`` ends both (so it can
    sit in a service's list of declarations)."""

    def __init__(self, twin: TwinGnss, publisher: Any):
        self.twin, self.publisher = twin, publisher

    def undeclare(self) -> None:
        self.twin.close()
        self.publisher.undeclare()


def start_twin_gnss(cfg: Any, parts: Any, session: Any, period_s: float = 0.1) -> _TwinGnssPublisher | None:
    """With the simulated tractor (``parts.tractor_node``), its GNSS receiver on ``<prefix>/tractor/gnss``:
    10 Hz fixes along the straight course ``cfg.sim_gnss_heading`` from ``cfg.sim_gnss_origin`` at the
    travelled distance the tractor's own wheel-based speed gives (``parts.sensors.distance_m``, the
    odometer) and its ground speed. None without a simulated tractor (a real one has a real receiver)."""
    tractor = getattr(parts, "tractor_node", None)
    if tractor is None:
        return None

    def speed() -> float:  # the wheel-based speed the tractor sends (with a field the twin's node has no constant)
        if tractor.ground_speed_m_s is not None:
            return float(tractor.ground_speed_m_s)
        v = parts.sensors.readings().speed.value
        return 0.0 if v is None else abs(float(v))

    twin = TwinGnss(
        parts.sensors.distance_m,
        speed,
        start=tuple(cfg.sim_gnss_origin),
        heading=float(cfg.sim_gnss_heading),
    )
    pub = session.declare_publisher(cfg.key("tractor/gnss"))
    twin.publish_every(pub.put, period_s)
    return _TwinGnssPublisher(twin, pub)


# ---------------------------------------------------------------------------------------- lines in the store
def lines_handlers(api: Any) -> dict[str, Callable[[Any], dict[str, Any]]]:
    """The ``lines/save|list|delete`` handlers of a :class:`~bridge.service.api.ServiceAPI`: the lines
    live in the control core's tracker (``motion.lines_request``) and in the store (kept across a
    restart, :func:`restore_lines`). A save or delete checks and changes under one lock: two saves of one new
    name at once are one save and one ``in_use``, never a silent replacement (a review)."""
    lock = threading.Lock()

    def save(r: Any) -> dict[str, Any]:
        with lock:
            return _save(r)

    def delete(r: Any) -> dict[str, Any]:
        with lock:
            return _delete(r)

    def _save(r: Any) -> dict[str, Any]:
        from bridge.service.schemas import RequestError

        lines = parse_lines(r.geojson, r.name)  # GnssError: nothing saved anywhere
        saved = {name for name, _ in api.store.list_lines()}
        again = [ln.name for ln in lines if ln.name in saved]
        if again and not r.replace:  # a typo in a name replaced a headland line silently (a field trial)
            raise RequestError(
                "in_use",
                f"lines/save: line(s) {', '.join(map(repr, again))} saved already; nothing was saved: send "
                '"replace": true (CLI: hitch lines save NAME FILE --replace) to replace them, or use other names',
            )
        out = dict(api.motion.lines_request("save", r.name, r.geojson))
        owner = getattr(api._caller, "user", None)
        for ln in lines:
            api.store.save_line(ln.name, ln.coordinates, owner=owner)
        if again:
            out["replaced"] = again
        return out

    def _delete(r: Any) -> dict[str, Any]:
        from bridge.service.maneuvers.recorder import maneuvers_using_line
        from bridge.service.schemas import RequestError

        users = maneuvers_using_line(api.store, r.name)
        if users and not r.force:  # those maneuvers would abort at the headland (trigger_unavailable)
            raise RequestError(
                "in_use",
                f"lines/delete: line {r.name!r} is waited for by the saved maneuver(s) {', '.join(users)}; send "
                "force: true (`hitch lines delete NAME --force`) to delete it anyway (those maneuvers then fail to "
                "validate, and a run aborts at that step: trigger_unavailable)",
            )
        stored = api.store.delete_line(r.name)
        try:
            out = dict(api.motion.lines_request("delete", r.name))
        except ValueError:  # not in the tracker (MotionError not_found): fine if it was stored
            if not stored:
                raise
            out = {"deleted": r.name}
        if users:
            out.update(warning=f"line {r.name!r} was waited for by {', '.join(users)}", maneuvers=users)
        return out

    return {
        "lines/save": save,
        "lines/list": lambda _r: dict(api.motion.lines_request("list")),
        "lines/delete": delete,
    }


def restore_lines(api: Any, lines_file: Any = None) -> list[str]:
    """Give the control core the store's lines, then the lines of the GeoJSON file ``lines_file`` (saved
    in the store too: they replace stored lines of the same name). Returns warnings (a line that could
    not be taken); raises :class:`GnssError` when the file cannot be read or parsed."""
    warnings = []
    for name, coords in api.store.list_lines():
        try:
            api.motion.lines_request("save", name, {"type": "LineString", "coordinates": coords})
        except ValueError as exc:  # GnssError (or the core's bad_request): a stored line this program refuses
            warnings.append(f"stored line {name!r} not loaded: {exc}")
    if lines_file is not None:
        text = read_text_file(Path(lines_file), "lines_file", GnssError)  # unreadable or not UTF-8: named
        try:
            lines = parse_lines(text)
        except GnssError as exc:
            raise GnssError(f"lines_file {str(lines_file)!r}: {exc}") from None
        for ln in lines:
            geo = {"type": "LineString", "coordinates": [list(c) for c in ln.coordinates]}
            api.motion.lines_request("save", ln.name, geo)
            api.store.save_line(ln.name, ln.coordinates)
    return warnings
