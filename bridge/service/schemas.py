"""Request schemas of the service API and the payload parser.

Every payload is bounded in size (:data:`MAX_PAYLOAD_BYTES`), decoded as UTF-8, parsed as JSON
(``NaN``/``Infinity`` tokens and numbers that overflow to infinity are refused naming their field;
a key written twice in one object is refused naming the key; nesting that exhausts the parser and
integers of thousands of digits are refused) and validated by a strict pydantic model per API key
(:data:`REQUESTS`): unknown fields, wrong types (no coercion: ``"1"`` is not a number, ``true`` is
not 1), non-finite numbers and out-of-range values are refused. :func:`parse_request` raises
:class:`RequestError` with a one-sentence message naming the key, the field, the value and the
allowed range. Units: x, z [m]; roll, pitch [rad]; rates [m/s, rad/s]; ``ttl_ms``, ``deadline_ms`` [ms].

* ``stop`` takes any payload (none, ``{}``, extra fields, garbage): whatever is sent to stop, stops.
* ``speed_scale`` lies in [:data:`MIN_SPEED_SCALE`, 1] = [0.05, 1]: plan time grows as 1/scale, and
  at 0.05 a move across the whole workspace plans in a fraction of a second.
* Every request that starts or resumes motion (``goto``, ``presets/go``, ``maneuvers/run``, ``jog``,
  ``hitch/raise``, ``hitch/return``, ``track/start``, ``maneuvers/resume``, ``maneuvers/skip``,
  ``work/start``, ``work/resume``) carries ``deadline_ms`` (integer 1…60000, default 1000): a request
  that cannot start within it is refused with ``busy`` by the service, never run later. The requests
  that only brake (``stop``, ``maneuvers/pause``, ``work/stop``) have none: they are never refused late.
* With the workspace (``parse_request(..., workspace=...)``, the service passes its
  ``limits.workspace``), a ``goto`` goal or a ``presets/save`` pose outside it is refused before
  the schema's sanity bounds (±1 m, ±2 m, ±π/2) with ``unreachable``, naming the workspace range of
  every violated DOF and hinting at mm/deg when the value fits in those units
  (:func:`check_pose_in_workspace`).
"""

from __future__ import annotations

import json
import math
import typing
from collections.abc import Mapping, Sequence
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, field_validator, model_validator
from pydantic.fields import FieldInfo

from bridge.service.event_ring import MAX_EVENTS_PER_REPLY
from bridge.service.maneuvers.language import MIN_SPEED_SCALE, NAME_PATTERN, POSE_BOUNDS
from bridge.service.maneuvers.steps import SETPOINT_VELOCITY_BOUND
from planner.errors import HitchInputError, distinct_texts, unit_hint, unit_hint_within
from planner.limits.tractor import IMPLEMENT_MASS_MAX_KG, IMPLEMENT_MASS_MIN_KG
from planner.model.limit_names import beyond_words
from planner.model.types import CONTROLLED_POSE_NAMES, CONTROLLED_POSE_UNITS

__all__ = [
    "API_KEYS",
    "ANY_PAYLOAD_KEYS",
    "MAX_PAYLOAD_BYTES",
    "MAX_SETPOINT_BYTES",
    "setpoint_too_large",
    "MIN_SPEED_SCALE",
    "DEFAULT_DEADLINE_MS",
    "MAX_DEADLINE_MS",
    "check_pose_in_workspace",
    "setpoint_session",
    "REQUESTS",
    "RequestError",
    "parse_request",
    "Goal",
    "PoseRequest",
    "PlanRequest",
    "GotoRequest",
    "JogRequest",
    "ModeRequest",
    "NameRequest",
    "PresetSave",
    "PresetGo",
    "ScriptRequest",
    "ManeuverSave",
    "ManeuverRun",
    "StopRequest",
    "SimFaultRequest",
    "TrackStart",
    "TrackStop",
    "TrackSetpoint",
    "TrackVelocity",
    "Empty",
    "EventsRecent",
    "MotionControl",
    "ImplementDefine",
    "QuickMove",
    "WorkSettingsRequest",
    "WorkStart",
]

MAX_PAYLOAD_BYTES = 96 * 1024  # a 64 KiB maneuver script, JSON-escaped, fits
#: a ``track/setpoint`` put's bound [bytes]: a setpoint is about 200 bytes (session, seq, four pose and four
#: rate values); the stream is taken in the control core's Zenoh session, beside ``stop``, so a larger put is
#: dropped unread (``setpoint_too_large``): 90 KB puts at full rate had delayed a stop by 8 s (a safety trial)
MAX_SETPOINT_BYTES = 2048
_NAME = NAME_PATTERN.pattern
#: deadline of a motion request [ms]: it must start within this time or is refused with ``busy``
DEFAULT_DEADLINE_MS = 1000
MAX_DEADLINE_MS = 60_000


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


def _whole(v: Any) -> Any:
    """A JSON number with no fraction written as a float (``1000.0``: what encoders of float64 numbers send for
    1000) is that integer; anything else goes to the strict check as it is (``1000.5``, ``true``, ``"1000"``)."""
    if isinstance(v, float) and v.is_integer() and abs(v) <= 2**53:
        return int(v)
    return v


#: an integer field that also takes an integral float (``1000.0``), never a bool, text or a fraction
WholeNumber = Annotated[int, BeforeValidator(_whole)]


def _dof(k: str, required: bool = False) -> Any:
    lo, hi = POSE_BOUNDS[k]
    return Field(... if required else None, ge=lo, le=hi)


class PoseRequest(_Strict):
    """A full pose: x, z [m]; roll, pitch [rad]."""

    x: float = _dof("x", True)
    z: float = _dof("z", True)
    roll: float = _dof("roll", True)
    pitch: float = _dof("pitch", True)


def _no_null_dof(data: Any, field: str, hint: str) -> Any:
    """Refuse a DOF of the partial pose ``data[field]`` given as ``null``, naming it (``goal.z must be a number
    (m), got null``): it is no number, and a DOF is left out, not null — a fleet trial's ``{"x": 0.01, "z":
    null}`` goto ran with z kept where it was, and ``{"z": null}`` was refused as "needs at least one of x, z,
    roll, pitch", its own DOF unnamed."""
    pose = data.get(field) if isinstance(data, dict) else None
    if isinstance(pose, dict):
        for k, v in pose.items():
            if v is None and k in CONTROLLED_POSE_NAMES:
                raise ValueError(f"{field}.{k} must be a number ({CONTROLLED_POSE_UNITS[k]}), got null; {hint}")
    return data


class Goal(_Strict):
    """A partial pose: unspecified DOF keep their current value."""

    x: float | None = _dof("x")
    z: float | None = _dof("z")
    roll: float | None = _dof("roll")
    pitch: float | None = _dof("pitch")

    @model_validator(mode="after")
    def _some(self) -> Goal:
        if all(getattr(self, k) is None for k in CONTROLLED_POSE_NAMES):
            raise RequestError("bad_request", "needs at least one of x, z, roll, pitch")
        return self

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in CONTROLLED_POSE_NAMES if getattr(self, k) is not None}


def _scale(default: float | None) -> Any:
    return Field(default, ge=MIN_SPEED_SCALE, le=1.0)


def _deadline() -> Any:
    return Field(DEFAULT_DEADLINE_MS, ge=1, le=MAX_DEADLINE_MS)


class Empty(_Strict):
    pass


class MotionControl(_Strict):
    """A request that resumes motion without other fields (``maneuvers/resume``, ``maneuvers/skip``,
    ``work/resume``): the deadline [ms] by which it must take effect."""

    deadline_ms: WholeNumber = _deadline()


class StopRequest(_Strict):
    """``stop`` has no fields, and :func:`parse_request` never looks at its payload: any payload stops."""


class PlanRequest(_Strict):
    goal: Goal

    @model_validator(mode="before")
    @classmethod
    def _no_null_goal(cls, data: Any) -> Any:
        return _no_null_dof(data, "goal", "a DOF left out keeps its value")

    speed_scale: float = _scale(1.0)


class GotoRequest(PlanRequest):
    """A goto: a plan request with the deadline [ms] by which the motion must start."""

    deadline_ms: WholeNumber = _deadline()


class JogRequest(_Strict):
    """Pose rates [m/s, rad/s] for ``ttl_ms`` milliseconds (dead-man: send again to keep moving)."""

    vx: float = Field(0.0, ge=-1.0, le=1.0)
    vz: float = Field(0.0, ge=-1.0, le=1.0)
    vroll: float = Field(0.0, ge=-1.0, le=1.0)
    vpitch: float = Field(0.0, ge=-1.0, le=1.0)
    ttl_ms: float = Field(200.0, gt=0.0, le=5000.0)
    deadline_ms: WholeNumber = _deadline()


class ModeRequest(_Strict):
    mode: Literal["auto", "manual", "attach", "transport", "config"] | None = None


class NameRequest(_Strict):
    name: str = Field(pattern=_NAME)


class PresetSave(_Strict):
    """Save a pose under a name; a name the implement has already is refused (``in_use``) unless ``replace``."""

    name: str = Field(pattern=_NAME)
    pose: Goal | None = None
    speed_scale: float | None = _scale(None)
    replace: bool = False

    @model_validator(mode="before")
    @classmethod
    def _no_null_pose(cls, data: Any) -> Any:
        return _no_null_dof(data, "pose", "a DOF left out keeps its value")


class PresetGo(_Strict):
    name: str = Field(pattern=_NAME)
    speed_scale: float | None = _scale(None)
    deadline_ms: WholeNumber = _deadline()


class ScriptRequest(_Strict):
    script: str = Field(max_length=64 * 1024)


class ManeuverSave(_Strict):
    """Store a maneuver; a name already saved is refused (``in_use``) unless ``replace``."""

    name: str = Field(pattern=_NAME)
    script: str = Field(max_length=64 * 1024)
    replace: bool = False


class ManeuverRun(NameRequest):
    """Run a stored maneuver; it must start within ``deadline_ms``."""

    deadline_ms: WholeNumber = _deadline()


class SimFaultRequest(_Strict):
    """Fault injection in the twin (``sim/fault``): a cut direction, frame loss [0, 1], extra
    delay [ms] and a one-off ECU restart; the whole setting is replaced (missing: no fault)."""

    cut: Literal["none", "planner_to_ecu", "ecu_to_planner", "both"] = "none"
    loss: float = Field(0.0, ge=0.0, le=1.0)
    delay_ms: float = Field(0.0, ge=0.0, le=5000.0)
    restart_ecu: bool = False


class TrackStart(_Strict):
    """Start a track session: setpoints of ``dof`` in ``frame`` (tractor, level: roll/pitch relative to
    gravity, ground: z above the ground); without a setpoint within ``ttl_ms`` the hitch brakes to rest.
    Another live session with a fresh stream is refused (``busy``) unless ``replace``: true takes over whatever
    session is live, a session number only that one (a take-over the operator confirmed for session N never takes
    over another that started meanwhile, e.g. work control's)."""

    frame: Literal["tractor", "level", "ground"] = "tractor"
    dof: list[Literal["x", "z", "roll", "pitch"]] = Field(min_length=1, max_length=4)
    ttl_ms: WholeNumber = Field(200, ge=50, le=1000)
    deadline_ms: WholeNumber = _deadline()
    replace: bool | Annotated[int, Field(ge=1)] = False

    @model_validator(mode="after")
    def _unique(self) -> TrackStart:
        if len(set(self.dof)) != len(self.dof):
            raise RequestError("bad_request", f"dof: each of x, z, roll, pitch at most once, got {list(self.dof)}")
        return self


class TrackStop(_Strict):
    """End the live track session smoothly (``session`` None: whichever is live). ``last_seq``: the
    last setpoint the client sent; it is taken before the follower brakes (a put may arrive after this
    query), waited for at most the session's ttl."""

    session: int | None = Field(None, ge=1)
    last_seq: int | None = Field(None, ge=0, le=2**53)

    # (an optional WholeNumber would lose its range in the JSON schema docs/api.md is made from)
    _whole_numbers = field_validator("session", "last_seq", mode="before")(_whole)


class TrackVelocity(_Strict):
    """Setpoint velocity [m/s, rad/s] of some DOF (missing: 0)."""

    x: float | None = Field(None, ge=-SETPOINT_VELOCITY_BOUND, le=SETPOINT_VELOCITY_BOUND)
    z: float | None = Field(None, ge=-SETPOINT_VELOCITY_BOUND, le=SETPOINT_VELOCITY_BOUND)
    roll: float | None = Field(None, ge=-SETPOINT_VELOCITY_BOUND, le=SETPOINT_VELOCITY_BOUND)
    pitch: float | None = Field(None, ge=-SETPOINT_VELOCITY_BOUND, le=SETPOINT_VELOCITY_BOUND)

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in CONTROLLED_POSE_NAMES if getattr(self, k) is not None}


class TrackSetpoint(_Strict):
    """One streamed setpoint (``track/setpoint``, a Zenoh put at up to 100 Hz): the session's DOFs in its
    frame [m, rad], optionally their velocity; ``seq`` strictly increasing (older ones are ignored)."""

    session: WholeNumber = Field(ge=1)
    seq: WholeNumber = Field(ge=0, le=2**53)
    pose: Goal
    velocity: TrackVelocity | None = None

    @model_validator(mode="before")
    @classmethod
    def _no_null_pose(cls, data: Any) -> Any:
        return _no_null_dof(data, "pose", "a DOF the session does not track is left out")


class PresetDelete(NameRequest):
    """Delete a preset; refused (``in_use``, naming the maneuvers) while a saved maneuver uses it unless ``force``."""

    force: bool = False


class RecordStop(_Strict):
    """End teach-in: the recorded script (YAML) is returned for review, named ``name`` if given (and saved as
    ``name``: a name already saved is refused, the recording going on, unless ``replace``)."""

    name: str | None = Field(None, pattern=_NAME)
    replace: bool = False


class LinesSave(_Strict):
    """Field-boundary / headland lines (GeoJSON LineString, Feature or FeatureCollection; ``[lon, lat]`` deg)."""

    name: str | None = Field(None, pattern=_NAME)
    geojson: dict[str, Any]
    replace: bool = False  # a line of a name saved already is refused (in_use) unless this

    @field_validator("geojson", mode="before")
    @classmethod
    def _geojson_object(cls, v: Any) -> Any:
        if not isinstance(v, dict):  # said as what it must be (pydantic's "a valid dictionary": a fuzz trial)
            raise ValueError(
                f"must be a GeoJSON object (LineString, Feature or FeatureCollection), got {type(v).__name__}"
            )
        return v


class LinesDelete(NameRequest):
    """Delete a line; refused (``in_use``, naming the maneuvers) while a saved maneuver waits for it unless
    ``force``."""

    force: bool = False


class ImplementDefine(_Strict):
    """Define (insert or replace) an implement: ISO 730 category, mass [kg], centre of mass [x, y, z] in the
    implement frame [m], optional upper height limit [m] (tool point z), lowering speed limit [m/s] and
    headland pose (a full pose; absent: the implement's preset ``headland``)."""

    name: str = Field(pattern=_NAME)
    category: Literal["1N", "1", "2N", "2", "3N", "3", "4N", "4"]
    # the tractor profile's range: (20, 20000] kg; a mass in tonnes (1.2) is refused with "did you mean t?" (a user
    # trial: [1, 20000] took it as 1.2 kg; 1e-300 was taken before that)
    mass_kg: float = Field(gt=IMPLEMENT_MASS_MIN_KG, le=IMPLEMENT_MASS_MAX_KG)
    com_m: list[Annotated[float, Field(ge=-10.0, le=10.0)]] = Field(min_length=3, max_length=3)
    upper_height_m: float | None = Field(None, ge=-1.0, le=2.0)
    lowering_speed_m_s: float | None = Field(None, ge=0.005, le=2.0)
    headland: PoseRequest | None = None
    description: str = Field("", max_length=200)


class QuickMove(_Strict):
    """``hitch/raise`` (to the headland pose) or ``hitch/return`` (to the last work pose)."""

    speed_scale: float | None = _scale(None)
    deadline_ms: WholeNumber = _deadline()


class SimSwitchRequest(_Strict):
    """``sim/switch``: the simulated tractor sends one momentary press of the operator's raise / lower
    switch (ISO 11783-7 PGN 65090; ``docs/implements.md``)."""

    position: Literal["raise", "lower", "released"]


class WorkSettingsRequest(_Strict):
    """``work/settings``: no field reads the selected implement's work-control settings; any field sets it
    (the others kept) and persists them for that implement (SI; the ranges: ``docs/soil.md``).
    ``slip_limit: null`` switches slip limiting off."""

    mode: Literal["position", "draft", "mixed", "float"] | None = None
    draft_setpoint_n: float | None = None
    blend: float | None = None
    sensitivity: float | None = None
    depth_min_m: float | None = None
    depth_max_m: float | None = None
    slip_limit: float | None = None


class WorkStart(_Strict):
    """``work/start``: a work session with the selected implement's settings; ``z``: the operator's
    position setpoint (tractor frame) [m], default the commanded z now."""

    z: float | None = Field(None, ge=-1.0, le=1.5)
    deadline_ms: WholeNumber = _deadline()


class EventsRecent(_Strict):
    """``events/recent``: the events numbered above ``after`` (``seq``), at most ``limit`` of them."""

    after: WholeNumber = Field(0, ge=0, le=2**53)
    limit: WholeNumber = Field(MAX_EVENTS_PER_REPLY, ge=1, le=MAX_EVENTS_PER_REPLY)


REQUESTS: Mapping[str, type[_Strict]] = {
    "ik": PoseRequest,
    "plan": PlanRequest,
    "goto": GotoRequest,
    "jog": JogRequest,
    "stop": StopRequest,
    "mode": ModeRequest,
    "config": Empty,
    "events/recent": EventsRecent,
    "presets/list": Empty,
    "presets/save": PresetSave,
    "presets/go": PresetGo,
    "presets/delete": PresetDelete,
    "maneuvers/validate": ScriptRequest,
    "maneuvers/save": ManeuverSave,
    "maneuvers/list": Empty,
    "maneuvers/run": ManeuverRun,
    "maneuvers/delete": NameRequest,
    "faults/ack": Empty,
    "sim/fault": SimFaultRequest,
    "track/start": TrackStart,
    "track/setpoint": TrackSetpoint,
    "track/stop": TrackStop,
    "maneuvers/pause": Empty,
    "maneuvers/resume": MotionControl,
    "maneuvers/skip": MotionControl,
    "maneuvers/record/start": Empty,
    "maneuvers/record/stop": RecordStop,
    "lines/save": LinesSave,
    "lines/list": Empty,
    "lines/delete": LinesDelete,
    "implements/list": Empty,
    "implements/define": ImplementDefine,
    "implements/select": NameRequest,
    "implements/delete": NameRequest,
    "implements/lock": Empty,
    "implements/unlock": Empty,
    "hitch/raise": QuickMove,
    "hitch/return": QuickMove,
    "sim/switch": SimSwitchRequest,
    "work/settings": WorkSettingsRequest,
    "work/start": WorkStart,
    "work/stop": Empty,
    "work/resume": MotionControl,
}
#: every API name (relative to the key prefix)
API_KEYS: tuple[str, ...] = tuple(REQUESTS)
#: keys whose payload is never read: anything sent to them is accepted (whatever is sent to stop, stops)
ANY_PAYLOAD_KEYS: frozenset[str] = frozenset({"stop"})
#: keys whose pose fields are checked against the workspace (when known) before the schema: key → field
#: ("": the payload's own fields, as work/start's operator setpoint z)
_POSE_FIELDS: Mapping[str, str] = {"goto": "goal", "presets/save": "pose", "work/start": ""}
#: keys that answer a goal outside the workspace with a preview (``plan``: ``refused``), not an error: a value
#: the schema refuses (beyond its plausible SI range, e.g. mm) is refused as ``goto`` refuses it (workspace
#: range and the mm / degrees hint) rather than with the schema's wider bound
_PREVIEW_POSE_FIELDS: Mapping[str, str] = {"plan": "goal"}


class RequestError(HitchInputError):
    """A request that cannot be served; ``code`` is the API error code."""

    def __init__(self, code: str, message: str):
        self.code = code
        super().__init__(message)


def _show(v: Any) -> str:
    """A value as JSON spells it (``true``, ``null``), short."""
    if isinstance(v, str):
        return repr(v if len(v) <= 40 else v[:40] + "…")
    if isinstance(v, bool) or v is None:
        return json.dumps(v)
    if isinstance(v, (int, float)):
        r = repr(v)
        return r if len(r) <= 40 else f"a number of {len(r)} digits"
    return f"a JSON {'object' if isinstance(v, dict) else 'array' if isinstance(v, list) else type(v).__name__}"


def _submodel(annotation: Any) -> type[BaseModel] | None:
    """The request model inside a field's annotation (``Goal | None`` → ``Goal``), if any."""
    subs = [
        a
        for a in (getattr(annotation, "__args__", None) or (annotation,))
        if isinstance(a, type) and issubclass(a, BaseModel)
    ]
    return subs[0] if subs else None


def _field_at(model: type[BaseModel], loc: tuple[int | str, ...]) -> tuple[FieldInfo | None, int]:
    """The field a validation error's ``loc`` points into, and how many parts of ``loc`` name it."""
    info: FieldInfo | None = None
    m: type[BaseModel] | None = model
    n = 0
    for part in loc:
        if not isinstance(part, str) or m is None or part not in m.model_fields:
            break
        info, n = m.model_fields[part], n + 1
        m = _submodel(info.annotation)
    return info, n


def _length_bounds(model: type[BaseModel], loc: tuple[int | str, ...]) -> tuple[object, object]:
    """The (min_length, max_length) of the list field at ``loc`` (0 and "any" where none is set)."""
    info, _ = _field_at(model, loc)
    meta = info.metadata if info is not None else []
    lo = next((c.min_length for c in meta if getattr(c, "min_length", None) is not None), 0)
    hi = next((c.max_length for c in meta if getattr(c, "max_length", None) is not None), "any")
    return lo, hi


def _item_metadata(annotation: Any) -> list[Any]:
    """The constraints on the items of a list field (``list[Annotated[float, Field(ge=…)]]``)."""
    args = typing.get_args(annotation)
    if not args or typing.get_origin(annotation) is not list:
        return []
    item = typing.get_args(args[0])  # Annotated[float, FieldInfo] → (float, FieldInfo)
    return [c for f in item[1:] for c in (f.metadata if isinstance(f, FieldInfo) else [f])]


def _bound(v: object) -> str:
    """A schema bound as a reader reads it: integers exactly (2**53, not 9.0072e+15), other numbers to 6 digits."""
    return str(v) if isinstance(v, int) and not isinstance(v, bool) else f"{v:.6g}"


#: the unit of a request field by its name (SI; "" for none), in refusals and in docs/api.md's table
FIELD_UNITS: Mapping[str, str] = {
    "x": "m",
    "z": "m",
    "roll": "rad",
    "pitch": "rad",
    "vx": "m/s",
    "vz": "m/s",
    "vroll": "rad/s",
    "vpitch": "rad/s",
    "ttl_ms": "ms",
    "deadline_ms": "ms",
    "delay_ms": "ms",
    "mass_kg": "kg",
    "com_m": "m",
    "upper_height_m": "m",
    "lowering_speed_m_s": "m/s",
}


def _unit(loc: tuple[int | str, ...]) -> str:
    """The unit of the field at ``loc`` ("" for none): a setpoint's ``velocity`` DOFs are rates."""
    name = next((str(p) for p in reversed(loc) if isinstance(p, str)), "")
    if "velocity" in loc and name in ("x", "z", "roll", "pitch"):  # a setpoint's velocity, not its position
        return "m/s" if name in ("x", "z") else "rad/s"
    return FIELD_UNITS.get(name, "")


def _allowed(model: type[BaseModel], loc: tuple[int | str, ...]) -> str:
    info, n = _field_at(model, loc)
    if info is None:
        return ""
    if n == len(loc) - 1 and isinstance(loc[-1], int):  # an item of a list field (``com_m.1``)
        metadata = _item_metadata(info.annotation)
    else:
        metadata = list(info.metadata)
    parts = [
        f"{sym} {_bound(getattr(c, a))}"
        for c in metadata
        for a, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="))
        if getattr(c, a, None) is not None
    ]
    unit = _unit(loc)
    unit = f" {unit}" if unit else ""
    return f" (allowed: {' and '.join(parts)}{unit})" if parts else ""


def _format(key: str, exc: ValidationError, model: type[BaseModel]) -> str:
    e = exc.errors(include_url=False)[0]
    loc = tuple(p for p in e["loc"] if not (isinstance(p, str) and p.startswith("function-")))
    path = ".".join(map(str, loc)) or "payload"
    if e["type"] == "extra_forbidden":
        parent: type[BaseModel] | None = model
        for p in loc[:-1]:
            info = parent.model_fields.get(p) if parent is not None and isinstance(p, str) else None
            parent = None if info is None else _submodel(info.annotation)
        fields = ", ".join(parent.model_fields) if parent is not None and parent.model_fields else "none"
        return f"{key}: unknown field {path!r} (allowed fields: {fields})"
    msg = e["msg"].removeprefix("Value error, ")
    if not loc and e["type"] == "value_error":  # a check of the whole payload: its message names the fields
        return f"{key}: {msg}"
    if e["type"] == "missing":
        return f"{key}: field {path!r} is required{_allowed(model, loc)}"
    if e["type"] == "finite_number":
        msg = "must be a finite number (NaN and infinity are not allowed)"
    elif e["type"] in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        msg = "is out of range"
    elif e["type"] == "string_pattern_mismatch":
        msg = "must be 1-64 letters, digits, '-', '_', '.' (ASCII only: a-z, A-Z, 0-9) starting with a letter or digit"
    elif e["type"] == "model_type":
        return f"{key}: {path} must be a JSON object, got {_show(e.get('input'))}"
    elif e["type"] in ("int_type", "int_from_float", "int_parsing"):
        msg = "must be an integer"
    elif e["type"] == "float_type" and _huge_int(e.get("input")):  # a number all the same: too large for any range
        msg = "is out of range" if _allowed(model, loc) else f"is out of range (a number lies within ±{_FLOAT_MAX:.4g})"
    elif e["type"] in ("float_type", "float_parsing"):
        given = e.get("input")
        msg = "must be a number" + (
            " (a JSON number, not text)"
            if isinstance(given, str)
            else " (true and false are not numbers)"
            if isinstance(given, bool)
            else ""
        )
    elif e["type"] in ("literal_error", "enum"):
        msg = f"must be one of {(e.get('ctx') or {}).get('expected', 'the allowed values')}"
    elif e["type"] == "string_type":
        msg = "must be text (a JSON string)"
    elif e["type"] in ("bool_type", "bool_parsing"):
        msg = "must be true or false"
    elif e["type"] == "list_type":
        msg = "must be a JSON list"
    elif e["type"] == "string_too_long":
        n = (e.get("ctx") or {}).get("max_length")
        size = f" ({n // 1024} KiB)" if isinstance(n, int) and n >= 1024 and n % 1024 == 0 else ""
        msg = f"is too long (allowed: at most {n} characters{size})"
        return f"{key}: {path} {msg}"
    elif e["type"] in ("too_short", "too_long"):
        lo, hi = _length_bounds(model, loc)
        n = (e.get("ctx") or {}).get("actual_length")
        want = f"exactly {lo}" if lo == hi else f"{lo}..{hi}"
        return f"{key}: {path} must hold {want} items, got {n if n is not None else 'another number'}"
    allowed = _allowed(model, loc)
    if msg == "is out of range" and isinstance(e.get("input"), (int, float)):
        value = _as_float(e["input"])
        allowed += "" if value is None else _range_hint(model, loc, value)
    return f"{key}: {path} = {_show(e.get('input'))} {msg}{allowed}"


#: the largest finite float: a JSON integer beyond it (309+ digits) has no float value
_FLOAT_MAX = 1.7976931348623157e308


def _huge_int(v: Any) -> bool:
    """An integer (not a bool) too large to be a float: pydantic's strict float refuses it as "not a number"."""
    return isinstance(v, int) and not isinstance(v, bool) and _as_float(v) is None


def _as_float(v: Any) -> float | None:
    """``v`` as a finite float; None for a non-number (a bool too), NaN, infinity and an integer beyond the float
    range (``float(10**400)`` raises OverflowError: a goto of z = 400 digits answered "internal error")."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    try:
        f = float(v)
    except OverflowError:
        return None
    return f if math.isfinite(f) else None


def _range_hint(model: type[BaseModel], loc: tuple[int | str, ...], value: float) -> str:
    """``; did you mean mm? …`` (or degrees) for a length [m] or angle [rad] out of its range that fits it read
    so (an engineer's report: `ik` with z = 200 named only the ±2 m, where goto hinted at mm)."""
    info, _ = _field_at(model, loc)
    return "" if info is None else unit_hint_within(value, info.metadata, _unit(loc))


class _NonFinite:
    """Stands in for a NaN/Infinity token (or a number that overflows) until its field is known."""

    __slots__ = ("token",)

    def __init__(self, token: str):
        self.token = token


def _constant(token: str) -> _NonFinite:
    return _NonFinite(token)


def _float(text: str) -> float | _NonFinite:
    v = float(text)
    return v if math.isfinite(v) else _NonFinite(text if len(text) <= 40 else f"a number of {len(text)} digits")


class _DuplicateKey(RequestError):
    def __init__(self, name: str):
        self.name = name
        super().__init__("bad_request", name)


def _pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


#: the deepest a request payload may nest (objects and lists; the deepest request, a GeoJSON feature collection
#: of lines, needs 6)
MAX_PAYLOAD_DEPTH = 32


def _scan(data: Any) -> tuple[bool, tuple[str, str] | None]:
    """One iterative walk of the decoded payload (no recursion): whether it nests deeper than
    :data:`MAX_PAYLOAD_DEPTH` levels (a scalar 0, ``{}`` 1), and the (path, token) of its first NaN/Infinity."""
    first: tuple[str, str] | None = None
    stack: list[tuple[Any, str, int]] = [(data, "", 1)]
    while stack:
        node, path, depth = stack.pop()
        if isinstance(node, _NonFinite):
            first = first or (path or "payload", node.token)
        elif isinstance(node, (dict, list)):
            if depth > MAX_PAYLOAD_DEPTH:
                return True, first
            if isinstance(node, dict):
                stack.extend((v, f"{path}.{k}" if path else str(k), depth + 1) for k, v in reversed(node.items()))
            else:
                stack.extend((v, f"{path}[{i}]", depth + 1) for i, v in reversed(list(enumerate(node))))
    return False, first


def setpoint_too_large(size: int) -> str | None:
    """The refusal of a ``track/setpoint`` put of ``size`` bytes, read before its payload is copied or parsed
    (None: within :data:`MAX_SETPOINT_BYTES`)."""
    if size <= MAX_SETPOINT_BYTES:
        return None
    return f"track/setpoint: payload is {size} bytes (allowed: at most {MAX_SETPOINT_BYTES}); dropped unread"


def setpoint_session(payload: bytes | bytearray | memoryview | str | None) -> int | None:
    """The ``session`` a ``track/setpoint`` payload names, read without validating the rest (None: not a
    JSON object with an integer ``session``): a setpoint refused by the schema is still counted against
    its session (:meth:`~bridge.service.motion.controller.MotionController.track_setpoint_refused`)."""
    try:
        data = json.loads(bytes(payload) if isinstance(payload, (bytearray, memoryview)) else (payload or b""))
    except (ValueError, TypeError, RecursionError):
        return None
    session = _whole(data.get("session")) if isinstance(data, dict) else None
    return session if isinstance(session, int) and not isinstance(session, bool) else None


def check_pose_in_workspace(
    pose: Mapping[str, Any], workspace: Mapping[str, Sequence[float]] | None, *, key: str = "goto", what: str = "goal"
) -> None:
    """:class:`RequestError` (``unreachable``) naming the workspace range of every DOF of ``pose``
    outside ``workspace`` (DOF name → [min, max]; x, z [m], roll, pitch [rad]), with a hint when
    the value fits in mm (x, z) or degrees (roll, pitch). Non-numbers (and integers beyond a float's range,
    309+ digits) are left to the schema, which refuses them naming the field and its range;
    ``workspace`` None: nothing to check. ``what``: the pose's field in the payload ("" when the pose
    fields are the payload's own, as ``work/start``'s ``z``)."""
    if not workspace or not isinstance(pose, Mapping):
        return
    problems = []
    for k in ("x", "z", "roll", "pitch"):
        v, rng = pose.get(k), workspace.get(k)
        v = _as_float(v)
        if rng is None or v is None:  # not a number, or no float (an integer of 309+ digits): the schema names it
            continue
        lo, hi = float(rng[0]), float(rng[1])
        if lo - 1e-9 <= v <= hi + 1e-9:
            continue
        unit = CONTROLLED_POSE_UNITS[k]
        side = beyond_words(k, high=v > hi)
        limit = f"workspace:{k}:{'min' if v < lo else 'max'}"
        name = f"{what}.{k}" if what else k
        shown, bound = distinct_texts(v, hi if v > hi else lo)
        lo_text, hi_text = (bound, f"{hi:.4g}") if v < lo else (f"{lo:.4g}", bound)
        text = f"{name} = {shown} {unit} is {side} the workspace ({k} from {lo_text} to {hi_text} {unit}, {limit})"
        text += unit_hint(v, lo, hi, unit)
        problems.append(text)
    if problems:
        raise RequestError("unreachable", f"{key}: outside the workspace: " + "; ".join(problems))


def parse_request(
    key: str,
    payload: bytes | bytearray | memoryview | str | None,
    *,
    workspace: Mapping[str, Sequence[float]] | None = None,
) -> BaseModel:
    """Bytes → validated request model of ``key``; :class:`RequestError` naming the field otherwise.

    ``workspace`` (DOF → [min, max], the service's ``limits.workspace``): pose fields of ``goto``
    and ``presets/save`` outside it are refused first, naming the workspace range
    (:func:`check_pose_in_workspace`).
    """
    model = REQUESTS.get(key)
    if model is None:
        raise RequestError("unknown_key", f"unknown API key {key!r}; allowed: {', '.join(API_KEYS)}")
    if key in ANY_PAYLOAD_KEYS:
        return model()  # never decoded: a stop must not be refused for what came with it
    raw = b"" if payload is None else payload
    if isinstance(raw, str):
        raw = raw.encode("utf-8", "surrogatepass")
    raw = bytes(raw)
    bound = MAX_SETPOINT_BYTES if key == "track/setpoint" else MAX_PAYLOAD_BYTES
    if len(raw) > bound:
        raise RequestError("bad_request", f"{key}: payload is {len(raw)} bytes (allowed: at most {bound})")
    if not raw.strip():
        data: Any = {}
    else:
        try:
            text = raw.decode("utf-8")
            data = json.loads(text, parse_constant=_constant, parse_float=_float, object_pairs_hook=_pairs)
        except _DuplicateKey as exc:
            raise RequestError(
                "bad_request", f"{key}: duplicate key {_show(exc.name)} in the payload (each field may appear once)"
            ) from None
        except UnicodeDecodeError as exc:
            raise RequestError("bad_request", f"{key}: payload is not UTF-8 text (byte {exc.start})") from None
        except RecursionError:
            raise RequestError(
                "bad_request", f"{key}: payload nests too deeply (allowed: at most {MAX_PAYLOAD_DEPTH} levels)"
            ) from None
        except ValueError as exc:  # JSONDecodeError, NaN/Infinity tokens, integers of > 4300 digits
            if "Exceeds the limit" in str(exc):  # Python's int parser: its message was cut in mid-word
                raise RequestError(
                    "bad_request", f"{key}: payload holds an integer of more than 4300 digits (no field takes one)"
                ) from None
            raise RequestError("bad_request", f"{key}: payload is not valid JSON ({str(exc)[:80]})") from None
    too_deep, bad = _scan(data)
    if too_deep:  # every request fits in a few levels; the limit is said (an attacker's report)
        raise RequestError(
            "bad_request",
            f"{key}: payload nests more than {MAX_PAYLOAD_DEPTH} levels deep "
            f"(allowed: at most {MAX_PAYLOAD_DEPTH} levels)",
        )
    if not isinstance(data, dict):
        raise RequestError(
            "bad_request",
            f"{key}: payload must be a JSON object with fields "
            f"{', '.join(model.model_fields) or '(none)'}, got {_show(data)}",
        )
    if bad is not None:
        path, token = bad
        loc = tuple(path.split("."))
        raise RequestError(
            "bad_request",
            f"{key}: {path} = {token} must be a finite number (NaN and infinity are not allowed){_allowed(model, loc)}",
        )
    if key in _POSE_FIELDS and workspace is not None:
        field = _POSE_FIELDS[key]
        check_pose_in_workspace((data.get(field) if field else data) or {}, workspace, key=key, what=field)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        if key in _PREVIEW_POSE_FIELDS and workspace is not None:
            pose = data.get(_PREVIEW_POSE_FIELDS[key])
            check_pose_in_workspace(pose or {}, workspace, key=key, what=_PREVIEW_POSE_FIELDS[key])
        raise RequestError("bad_request", _format(key, exc, model)) from None
    except RecursionError:
        raise RequestError(
            "bad_request", f"{key}: payload nests too deeply (allowed: at most {MAX_PAYLOAD_DEPTH} levels)"
        ) from None
