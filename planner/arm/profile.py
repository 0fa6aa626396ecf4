"""Serial-arm profiles: a DH table with joint limits, base and tool frames, from TOML.

Every number is SI: lengths in metres, angles in radians. The schema is strict (pydantic
strict mode, unknown keys rejected): a wrong type, a missing key or a value out of range
raises :class:`ArmProfileError` whose message names the field, the value and what is allowed.

Schema (``schema_version = 1``)::

    name = "arm-source-example"        # letters, digits, '-', '_', '.'
    description = "..."
    [[joints]]                         # one table per joint, base to tool (1..12)
    name = "waist"
    type = "revolute"                  # or "prismatic"
    a = 0.0                            # [m]   link length along x_i, |a| <= 10
    alpha = 1.5707963267948966         # [rad] link twist about x_i, |alpha| <= 2π
    d = 0.100                          # [m]   offset along z_{i-1} (+ q if prismatic), |d| <= 10
    theta = 0.0                        # [rad] angle about z_{i-1} (+ q if revolute), |theta| <= 2π
    lower = -3.141592653589793         # joint limits [rad] (revolute, within ±2π)
    upper = 3.141592653589793          #   or [m] (prismatic, within ±10)
    [base]                             # optional: frame 0 in the world frame
    position = [0.0, 0.0, 0.0]         # [m], each within ±100
    zyz = [0.0, 0.0, 0.0]              # [rad] ZYZ Euler angles (phi, theta, psi), within ±2π
    [tool]                             # optional: tool frame in frame n (same keys; position within ±10 m)

Lengths are bounded by 10 m (:data:`planner.arm.dh.MAX_LENGTH`): no serial arm of this product
comes near it, and millimetres typed as metres (``a = 100.0``) exceed it; such an error, and a
revolute angle typed in degrees, carries a "did you mean mm?" / "did you mean degrees?" hint.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from planner.arm.dh import MAX_LENGTH, DHChain, DHLink, build_dh_chain
from planner.arm.transforms import euler_zyz_matrix, homogeneous
from planner.errors import HitchInputError, unit_hint
from planner.profiles.loader import builtin_profiles, check_profile_name, format_validation_error, read_profile

__all__ = [
    "ArmProfileError",
    "JointSpec",
    "FrameSpec",
    "ArmProfile",
    "load_arm_profile",
    "arm_profile_from_dict",
    "available_arm_profiles",
    "DEFAULT_ARM_PROFILE",
]

#: Built-in profile used when none is named.
DEFAULT_ARM_PROFILE = "arm-source-example"
_TWO_PI = 2.0 * math.pi
#: |a|, |d|, prismatic limits and the tool position [m] (see the module docstring).
_MAX_LENGTH = MAX_LENGTH
#: Base position components [m]: where the arm stands in the world frame may lie farther out.
_MAX_BASE_POSITION = 100.0


class ArmProfileError(HitchInputError):
    """An arm profile that cannot be used; the message names field, value and allowed range."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class JointSpec(_Strict):
    """One DH row and its joint (units in the module docstring)."""

    name: str = Field(min_length=1, max_length=40)
    type: Literal["revolute", "prismatic"] = "revolute"
    a: float = Field(allow_inf_nan=False)
    alpha: float = Field(allow_inf_nan=False)
    d: float = Field(allow_inf_nan=False)
    theta: float = Field(allow_inf_nan=False)
    lower: float = Field(allow_inf_nan=False)
    upper: float = Field(allow_inf_nan=False)

    @field_validator("a", "d")
    @classmethod
    def _length(cls, v: float, info) -> float:
        if abs(v) > _MAX_LENGTH:
            raise ArmProfileError(
                f"{info.field_name} = {v} m is outside the allowed [-{_MAX_LENGTH:g}, {_MAX_LENGTH:g}] m"
                + unit_hint(v, -_MAX_LENGTH, _MAX_LENGTH, "m")
            )
        return v

    @field_validator("alpha", "theta")
    @classmethod
    def _angle(cls, v: float, info) -> float:
        if abs(v) > _TWO_PI:
            raise ArmProfileError(
                f"{info.field_name} = {v} rad is outside the allowed [-2π, 2π] rad"
                + unit_hint(v, -_TWO_PI, _TWO_PI, "rad")
            )
        return v

    @model_validator(mode="after")
    def _limits(self):
        if not self.lower < self.upper:
            raise ArmProfileError(f"joint {self.name!r}: limits need lower < upper (got [{self.lower}, {self.upper}])")
        bound, unit = (_TWO_PI, "rad") if self.type == "revolute" else (_MAX_LENGTH, "m")
        for side in ("lower", "upper"):
            v = getattr(self, side)
            if abs(v) > bound:
                raise ArmProfileError(
                    f"joint {self.name!r}: {side} = {v} {unit} is outside the allowed ±{bound:.6g} {unit} "
                    f"for a {self.type} joint" + unit_hint(v, -bound, bound, unit)
                )
        return self

    def link(self) -> DHLink:
        return DHLink(self.a, self.alpha, self.d, self.theta, self.type, self.lower, self.upper, self.name)


class FrameSpec(_Strict):
    """A fixed frame: position [m] and ZYZ Euler angles [rad] (arm thesis 2.10)."""

    position: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    zyz: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)

    @field_validator("position")
    @classmethod
    def _position(cls, v: list[float]) -> list[float]:
        for x in v:
            if not math.isfinite(x):
                raise ArmProfileError("position components must be finite")
            if abs(x) > _MAX_BASE_POSITION:
                raise ArmProfileError(
                    f"position component {x} m is outside the allowed ±{_MAX_BASE_POSITION:g} m"
                    + unit_hint(x, -_MAX_BASE_POSITION, _MAX_BASE_POSITION, "m")
                )
        return v

    @field_validator("zyz")
    @classmethod
    def _zyz(cls, v: list[float]) -> list[float]:
        if not all(math.isfinite(x) and abs(x) <= _TWO_PI for x in v):
            raise ArmProfileError("zyz angles must be finite and within ±2π rad")
        return v

    def transform(self):
        return homogeneous(euler_zyz_matrix(*self.zyz), self.position)


class ArmProfile(_Strict):
    """A serial arm: DH joints, base and tool frames."""

    schema_version: Literal[1]
    name: str = Field(min_length=1, max_length=80)
    description: str = ""
    joints: list[JointSpec] = Field(min_length=1, max_length=12)
    base: FrameSpec = Field(default_factory=FrameSpec)
    tool: FrameSpec = Field(default_factory=FrameSpec)

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return check_profile_name(v)

    @model_validator(mode="after")
    def _unique(self):
        names = [j.name for j in self.joints]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ArmProfileError(f"joint names must be unique; repeated: {', '.join(dup)}")
        return self

    @field_validator("tool")
    @classmethod
    def _tool(cls, v: FrameSpec) -> FrameSpec:
        for i, x in enumerate(v.position):  # the tool offset is a link of the arm: ±10 m, like a and d
            if abs(x) > _MAX_LENGTH:
                raise ArmProfileError(
                    f"position[{i}] = {x} m is outside the allowed ±{_MAX_LENGTH:g} m for the tool"
                    + unit_hint(x, -_MAX_LENGTH, _MAX_LENGTH, "m")
                )
        return v

    def chain(self) -> DHChain:
        """The :class:`~planner.arm.dh.DHChain` this profile describes."""
        return build_dh_chain([j.link() for j in self.joints], base=self.base.transform(), tool=self.tool.transform())


def available_arm_profiles() -> list[str]:
    """Names of the arm profiles shipped with the package (``planner/profiles/arms/*.toml``)."""
    return builtin_profiles("arms")


def arm_profile_from_dict(data: dict, source: str = "<dict>") -> ArmProfile:
    """Validate an arm profile given as a dictionary (as parsed from TOML)."""
    if not isinstance(data, dict):
        raise ArmProfileError(f"arm profile {source} must be a table, got {type(data).__name__}")
    try:
        return ArmProfile.model_validate(data)
    except ValidationError as exc:
        raise ArmProfileError(format_validation_error("arm profile", source, exc, ArmProfile)) from None


def load_arm_profile(name_or_path: str | Path = DEFAULT_ARM_PROFILE) -> ArmProfile:
    """Load and validate an arm profile by built-in name (``arm-…``) or by file path."""
    source, data = read_profile(name_or_path, subfolder="arms", kind="arm profile", error=ArmProfileError)
    return arm_profile_from_dict(data, source=source)
