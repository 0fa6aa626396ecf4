"""The step schema of the maneuver language: one strict pydantic model per step kind.

:class:`GotoStep`, :class:`PresetStep`, :class:`WaitStep`, :class:`WaitForStep` and
:class:`SpeedStep` (the union :data:`Step`), the script header and the parsed
:class:`ManeuverScript`, with the bounds they check (:data:`POSE_BOUNDS`,
:data:`NAME_PATTERN`, timeouts) and :func:`check_name`. The language itself (parsing,
error reporting, validation by planning) is in :mod:`bridge.service.maneuvers.language`, which
re-exports these names.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from planner.errors import HitchInputError
from planner.model.types import CONTROLLED_POSE_UNITS

__all__ = [
    "ManeuverSchemaError",
    "DEFAULT_TIMEOUT_S",
    "MAX_TIMEOUT_S",
    "MIN_SPEED_SCALE",
    "POSE_BOUNDS",
    "SETPOINT_VELOCITY_BOUND",
    "NAME_PATTERN",
    "GotoStep",
    "PresetStep",
    "WaitStep",
    "WaitForStep",
    "SpeedStep",
    "Step",
    "ManeuverScript",
    "check_name",
    "step_words",
]

DEFAULT_TIMEOUT_S = 60.0
MAX_TIMEOUT_S = 3600.0
#: the lowest speed scale a motion may ask for: plan time grows as 1/scale (a full-workspace move
#: plans in ~0.2 s at 0.05, ~10 s at 0.001), so lower scales are refused, never planned
MIN_SPEED_SCALE = 0.05
#: sanity bounds of a hitch pose (x, z [m]; roll, pitch [rad]); the workspace check is the planner's
POSE_BOUNDS: Mapping[str, tuple[float, float]] = {
    "x": (-1.0, 1.0),
    "z": (-2.0, 2.0),
    "roll": (-math.pi / 2, math.pi / 2),
    "pitch": (-math.pi / 2, math.pi / 2),
}
#: the largest |velocity| a track setpoint may carry [m/s, rad/s] (the track/setpoint schema's bound)
SETPOINT_VELOCITY_BOUND = 1.0
#: names of maneuvers, presets and implements
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}$")


class ManeuverSchemaError(HitchInputError):
    """A value the step schema refuses (a name, a goto without a pose); the message says what is allowed.

    Raised by :func:`check_name`; inside the step models pydantic turns it into a validation error.
    """


def check_name(value: Any, what: str = "name") -> str:
    """A name of 1–64 letters, digits, '-', '_', '.', starting with a letter or digit."""
    if not isinstance(value, str) or not NAME_PATTERN.match(value):
        raise ManeuverSchemaError(
            f"{what} must be 1-64 characters of letters, digits, '-', '_', '.' starting with a "
            f"letter or digit, got {_show(value)}"
        )
    return value


def step_words(index: int, kind: str | None = None) -> str:
    """A step as every text names it: counted from 1 as a reader counts a script's steps, with the API's
    0-based index (``step`` in events, errors and the state; ``steps[i]``) beside it — ``step 2 (index 1)``,
    ``step 2 (index 1, goto)``. (The CLI and the page said "step 0" at run time and "step 1" in validate.)"""
    return f"step {index + 1} (index {index}{', ' + kind if kind else ''})"


def _show(value: Any) -> str:
    """A short, safe rendering of a user value (containers are never expanded)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**15:
        try:
            return f"an integer of {len(str(abs(value)))} digits"
        except ValueError:  # beyond Python's int-to-str limit
            return "a huge integer"
    if isinstance(value, (bool, int, float)) or value is None:
        return repr(value)
    if isinstance(value, str):
        return repr(value if len(value) <= 40 else value[:40] + "…")
    return f"a {type(value).__name__}"


# ---------------------------------------------------------------------------------------- schema
class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


def _pose_field(k: str) -> Any:
    lo, hi = POSE_BOUNDS[k]
    return Field(None, ge=lo, le=hi)


class GotoStep(_Strict):
    """Move to a (partial) pose: x, z [m], roll, pitch [rad]; optional speed scale [0.05, 1]."""

    kind: ClassVar[str] = "goto"
    x: float | None = _pose_field("x")
    z: float | None = _pose_field("z")
    roll: float | None = _pose_field("roll")
    pitch: float | None = _pose_field("pitch")
    speed_scale: float | None = Field(None, ge=MIN_SPEED_SCALE, le=1.0)

    @model_validator(mode="before")
    @classmethod
    def _no_null(cls, data: Any) -> Any:
        """A DOF given as null (JSON ``null``, YAML ``~`` or an empty value) is no number: named, as ``goto``'s
        goal refuses it (a review: ``{x: 0.01, z: null}`` ran with z kept where it was)."""
        if isinstance(data, dict):
            for k, v in data.items():
                if v is None and k in POSE_BOUNDS:
                    raise ManeuverSchemaError(
                        f"{k} must be a number ({CONTROLLED_POSE_UNITS[k]}), got null; a DOF left out keeps its value"
                    )
        return data

    @model_validator(mode="after")
    def _some_dof(self) -> GotoStep:
        if all(getattr(self, k) is None for k in POSE_BOUNDS):
            raise ManeuverSchemaError("goto needs at least one of x, z, roll, pitch")
        return self

    @property
    def goal(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in POSE_BOUNDS if getattr(self, k) is not None}


class PresetStep(_Strict):
    """Move to a saved preset of the current implement; optional speed scale [0.05, 1]."""

    kind: ClassVar[str] = "preset"
    name: str
    speed_scale: float | None = Field(None, ge=MIN_SPEED_SCALE, le=1.0)

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return check_name(v, "preset name")


class WaitStep(_Strict):
    """Wait ``seconds`` (0, 3600] s."""

    kind: ClassVar[str] = "wait"
    seconds: float = Field(gt=0.0, le=MAX_TIMEOUT_S)


class WaitForStep(_Strict):
    """Wait for the tractor: exactly one of ``distance`` (0, 10000] m travelled (wheel-based speed)
    or ``line``, a named field-boundary / headland line reached (GNSS position,
    :mod:`bridge.service.gnss`). ``complete: true`` (only with ``line``): the next motion step must
    be complete when the line is reached, so it starts early — at the planned duration of that
    step × the current ground speed before the line (lead compensation)."""

    kind: ClassVar[str] = "wait_for"
    distance: float | None = Field(None, gt=0.0, le=10_000.0)
    line: str | None = None
    complete: bool | None = None

    @field_validator("line")
    @classmethod
    def _line(cls, v: str | None) -> str | None:
        return None if v is None else check_name(v, "line name")

    @model_validator(mode="after")
    def _one_trigger(self) -> WaitForStep:
        if (self.distance is None) == (self.line is None):
            raise ManeuverSchemaError("wait_for needs exactly one of distance (m) or line (a line name)")
        if self.complete is not None and self.line is None:
            raise ManeuverSchemaError("wait_for.complete is allowed only with line (lead compensation at a line)")
        return self


class SpeedStep(_Strict):
    """Speed scale [0.05, 1] for the following motion steps."""

    kind: ClassVar[str] = "speed"
    scale: float = Field(ge=MIN_SPEED_SCALE, le=1.0)


Step = GotoStep | PresetStep | WaitStep | WaitForStep | SpeedStep
#: step key → (model, name of the field a scalar value fills, or None if the value must be a mapping)
_KINDS: Mapping[str, tuple[type[Step], str | None]] = {
    "goto": (GotoStep, None),
    "preset": (PresetStep, "name"),
    "wait": (WaitStep, "seconds"),
    "wait_for": (WaitForStep, None),
    "speed": (SpeedStep, "scale"),
}


class _Header(_Strict):
    name: str | None = None
    description: str = Field("", max_length=1000)
    timeout: float = Field(DEFAULT_TIMEOUT_S, gt=0.0, le=MAX_TIMEOUT_S)

    @field_validator("name")
    @classmethod
    def _name(cls, v: str | None) -> str | None:
        return None if v is None else check_name(v, "name")


@dataclass(frozen=True)
class ManeuverScript:
    """A parsed, schema-valid maneuver."""

    name: str | None
    description: str
    timeout_s: float
    steps: tuple[Step, ...]

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "description": self.description,
            "timeout": self.timeout_s,
            "steps": [{s.kind: s.model_dump(exclude_none=True)} for s in self.steps],
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ManeuverScript:
        """The script back from :meth:`to_json` (no YAML: one model validation per step).

        Raises :class:`ManeuverSchemaError` if ``data`` is not such a form.
        """
        try:
            steps = []
            for entry in data["steps"]:
                ((kind, value),) = entry.items()
                steps.append(_KINDS[kind][0].model_validate(value))
            header = _Header.model_validate(
                {"name": data["name"], "description": data["description"], "timeout": data["timeout"]}
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:  # pydantic's ValidationError is a ValueError
            raise ManeuverSchemaError(
                f"not a parsed maneuver script ({type(exc).__name__}: {str(exc)[:120]})"
            ) from None
        return cls(header.name, header.description, header.timeout, tuple(steps))
