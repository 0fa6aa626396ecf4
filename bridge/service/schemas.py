"""Request schemas of the service API and the payload parser.

Every payload is bounded in size (:data:`MAX_PAYLOAD_BYTES`), decoded as UTF-8, parsed as JSON
(``NaN``/``Infinity`` tokens, nesting that exhausts the parser and integers of thousands of
digits are refused) and validated by a strict pydantic model per API key (:data:`REQUESTS`):
unknown fields, wrong types (no coercion: ``"1"`` is not a number, ``true`` is not 1),
non-finite numbers and out-of-range values are refused. :func:`parse_request` raises
:class:`RequestError` with a one-sentence message naming the key, the field, the value and the
allowed range. Units: x, z [m]; roll, pitch [rad]; rates [m/s, rad/s]; ``ttl_ms`` [ms].
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from pydantic.fields import FieldInfo

from bridge.service.maneuvers.language import NAME_PATTERN, POSE_BOUNDS
from planner.errors import HitchInputError
from planner.model.types import CONTROLLED_POSE_NAMES

__all__ = [
    "API_KEYS",
    "MAX_PAYLOAD_BYTES",
    "REQUESTS",
    "RequestError",
    "parse_request",
    "Goal",
    "PoseRequest",
    "PlanRequest",
    "JogRequest",
    "ModeRequest",
    "NameRequest",
    "PresetSave",
    "PresetGo",
    "ScriptRequest",
    "ManeuverSave",
    "Empty",
]

MAX_PAYLOAD_BYTES = 96 * 1024  # a 64 KiB maneuver script, JSON-escaped, fits
_NAME = NAME_PATTERN.pattern


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


def _dof(k: str, required: bool = False) -> Any:
    lo, hi = POSE_BOUNDS[k]
    return Field(... if required else None, ge=lo, le=hi)


class PoseRequest(_Strict):
    """A full pose: x, z [m]; roll, pitch [rad]."""

    x: float = _dof("x", True)
    z: float = _dof("z", True)
    roll: float = _dof("roll", True)
    pitch: float = _dof("pitch", True)


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


_SCALE = Field(1.0, gt=0.0, le=1.0)


class Empty(_Strict):
    pass


class PlanRequest(_Strict):
    goal: Goal
    speed_scale: float = _SCALE


class JogRequest(_Strict):
    """Pose rates [m/s, rad/s] for ``ttl_ms`` milliseconds (dead-man: send again to keep moving)."""

    vx: float = Field(0.0, ge=-1.0, le=1.0)
    vz: float = Field(0.0, ge=-1.0, le=1.0)
    vroll: float = Field(0.0, ge=-1.0, le=1.0)
    vpitch: float = Field(0.0, ge=-1.0, le=1.0)
    ttl_ms: float = Field(200.0, gt=0.0, le=5000.0)


class ModeRequest(_Strict):
    mode: Literal["auto", "manual", "attach", "transport", "config"] | None = None


class NameRequest(_Strict):
    name: str = Field(pattern=_NAME)


class PresetSave(_Strict):
    name: str = Field(pattern=_NAME)
    pose: Goal | None = None
    speed_scale: float | None = Field(None, gt=0.0, le=1.0)


class PresetGo(_Strict):
    name: str = Field(pattern=_NAME)
    speed_scale: float | None = Field(None, gt=0.0, le=1.0)


class ScriptRequest(_Strict):
    script: str = Field(max_length=64 * 1024)


class ManeuverSave(_Strict):
    name: str = Field(pattern=_NAME)
    script: str = Field(max_length=64 * 1024)


REQUESTS: Mapping[str, type[_Strict]] = {
    "ik": PoseRequest,
    "plan": PlanRequest,
    "goto": PlanRequest,
    "jog": JogRequest,
    "stop": Empty,
    "mode": ModeRequest,
    "config": Empty,
    "presets/list": Empty,
    "presets/save": PresetSave,
    "presets/go": PresetGo,
    "presets/delete": NameRequest,
    "maneuvers/validate": ScriptRequest,
    "maneuvers/save": ManeuverSave,
    "maneuvers/list": Empty,
    "maneuvers/run": NameRequest,
    "maneuvers/delete": NameRequest,
}
#: every API name (relative to the key prefix)
API_KEYS: tuple[str, ...] = tuple(REQUESTS)


class RequestError(HitchInputError):
    """A request that cannot be served; ``code`` is the API error code."""

    def __init__(self, code: str, message: str):
        self.code = code
        super().__init__(message)


def _show(v: Any) -> str:
    if isinstance(v, str):
        return repr(v if len(v) <= 40 else v[:40] + "…")
    if isinstance(v, (bool, int, float)) or v is None:
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


def _allowed(model: type[BaseModel], loc: tuple[int | str, ...]) -> str:
    info: FieldInfo | None = None
    m: type[BaseModel] | None = model
    for part in loc:
        if not isinstance(part, str) or m is None or part not in m.model_fields:
            break
        info = m.model_fields[part]
        m = _submodel(info.annotation)
    if info is None:
        return ""
    parts = [
        f"{sym} {getattr(c, a):.6g}"
        for c in info.metadata
        for a, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="))
        if getattr(c, a, None) is not None
    ]
    name = str(loc[-1]) if loc else ""
    unit = {
        "x": " m",
        "z": " m",
        "roll": " rad",
        "pitch": " rad",
        "vx": " m/s",
        "vz": " m/s",
        "vroll": " rad/s",
        "vpitch": " rad/s",
        "ttl_ms": " ms",
    }.get(name, "")
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
    if e["type"] == "missing":
        return f"{key}: field {path!r} is required{_allowed(model, loc)}"
    if e["type"] == "finite_number":
        msg = "must be a finite number (NaN and infinity are not allowed)"
    elif e["type"] in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        msg = "is out of range"
    elif e["type"] == "string_pattern_mismatch":
        msg = "must be 1-64 letters, digits, '-', '_', '.' starting with a letter or digit"
    elif e["type"] == "model_type":
        msg = "must be a JSON object"
    return f"{key}: {path} = {_show(e.get('input'))} {msg}{_allowed(model, loc)}"


def _reject_constant(token: str) -> None:
    raise RequestError("bad_request", f"{token} is not a number JSON allows")


def parse_request(key: str, payload: bytes | bytearray | memoryview | str | None) -> BaseModel:
    """Bytes → validated request model of ``key``; :class:`RequestError` naming the field otherwise."""
    model = REQUESTS.get(key)
    if model is None:
        raise RequestError("unknown_key", f"unknown API key {key!r}; allowed: {', '.join(API_KEYS)}")
    raw = b"" if payload is None else payload
    if isinstance(raw, str):
        raw = raw.encode("utf-8", "surrogatepass")
    raw = bytes(raw)
    if len(raw) > MAX_PAYLOAD_BYTES:
        raise RequestError("bad_request", f"{key}: payload is {len(raw)} bytes (allowed: at most {MAX_PAYLOAD_BYTES})")
    if not raw.strip():
        data: Any = {}
    else:
        try:
            text = raw.decode("utf-8")
            data = json.loads(text, parse_constant=_reject_constant)
        except UnicodeDecodeError as exc:
            raise RequestError("bad_request", f"{key}: payload is not UTF-8 text (byte {exc.start})") from None
        except RecursionError:
            raise RequestError("bad_request", f"{key}: payload nests too deeply") from None
        except ValueError as exc:  # JSONDecodeError, NaN/Infinity tokens, integers of > 4300 digits
            raise RequestError("bad_request", f"{key}: payload is not valid JSON ({str(exc)[:80]})") from None
    if not isinstance(data, dict):
        raise RequestError(
            "bad_request",
            f"{key}: payload must be a JSON object with fields "
            f"{', '.join(model.model_fields) or '(none)'}, got {_show(data)}",
        )
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise RequestError("bad_request", _format(key, exc, model)) from None
    except RecursionError:
        raise RequestError("bad_request", f"{key}: payload nests too deeply") from None
