"""Tractor parameters and implement records for the stability measures.

Two layers, as in :mod:`planner.profiles.hitch`: a strict pydantic schema that reads a tractor
profile (TOML, e.g. ``planner/profiles/tractors/tractor-6t.toml``) and rejects unknown keys, wrong
types, NaN/inf and out-of-range values with a :class:`TractorProfileError` naming the field;
and frozen dataclass values (:class:`Tractor`, :class:`ImplementRecord`) taken by the pure
functions of :mod:`planner.limits.stability`.

Frames. A profile gives tractor points the way they are measured on a real tractor: ``x``
lateral (+ to the driver's left), ``y`` longitudinal from the lower-link pivots (+ rearward,
towards the implement) and ``height`` above flat ground.  :func:`build_tractor` places them in
the hitch's tractor frame (origin midway between the lower-link pivots at pivot height, x left,
y rearward, z up) given the hitch profile's ``geometry.pivot_height`` h_p: a point at height h
gets z = h - h_p, and the ground is the plane z = -h_p.  Implement records give the centre of
mass in the implement frame (origin at the tool point T, x_i along R->L, z_i along the mast,
y_i = z_i x x_i, rearward when the mast is upright).

Support. The front axle oscillates about a longitudinal pivot, so the tractor stands on a
triangle: the two rear tyre contacts and the front-axle pivot (the classic tractor stability
triangle; the oscillation stops are not modelled).  The rear contacts lie straight below the
rear-axle centre, ``rear_track`` apart; the pivot is on the centre line one wheelbase ahead.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from planner.errors import HitchInputError, unit_hint
from planner.profiles.loader import format_validation_error, read_profile

__all__ = [
    "STANDARD_GRAVITY",
    "ISO730_CATEGORIES",
    "IMPLEMENT_MASS_MIN_KG",
    "IMPLEMENT_MASS_MAX_KG",
    "StabilityInputError",
    "TractorProfileError",
    "Tractor",
    "ImplementRecord",
    "TractorSpec",
    "ImplementSpec",
    "TractorProfileSpec",
    "TractorProfile",
    "build_tractor",
    "load_tractor_profile",
    "tractor_profile_from_dict",
]

#: Standard gravity g_n [m/s²] (weights in N = mass [kg] · g_n).
STANDARD_GRAVITY: float = 9.80665
#: ISO 730 implement categories (thesis table 3-6).
ISO730_CATEGORIES: tuple[str, ...] = ("1N", "1", "2N", "2", "3N", "3", "4N", "4")
#: the lightest empty tractor a profile may give [kg] (sub-compact tractors with a three-point hitch weigh more)
TRACTOR_MASS_MIN_KG: float = 300.0
#: an implement's mass [kg], a tractor profile's record and the service's ``implements/define`` alike: more than
#: IMPLEMENT_MASS_MIN_KG (no three-point implement weighs 20 kg or less; every mass up to it could be typed in tonnes
#: and is refused with the tonnes reading: "did you mean t? 1.2 t = 1200 kg") up to IMPLEMENT_MASS_MAX_KG. Before,
#: (0, 20000] here and [1, 20000] in the service took 1.65 (t) as a 1.65 kg implement (a user trial)
IMPLEMENT_MASS_MIN_KG: float = 20.0
IMPLEMENT_MASS_MAX_KG: float = 20_000.0
Category = Literal["1N", "1", "2N", "2", "3N", "3", "4N", "4"]


class StabilityInputError(HitchInputError):
    """A tractor, implement, pose or slope the stability measures cannot use; names the field."""


class TractorProfileError(StabilityInputError):
    """A tractor profile that cannot be used; the message names field, value and allowed range."""


def _scalar(name: str, value, lo: float = -math.inf, hi: float = math.inf, *, open_lo: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise StabilityInputError(f"{name} must be a number, got {value!r}") from None
    below = v <= lo if open_lo else v < lo
    if not math.isfinite(v) or below or v > hi:
        bracket = "(" if open_lo else "["
        raise StabilityInputError(f"{name} = {value!r} is outside the allowed range {bracket}{lo}, {hi}]")
    return v


def _vector3(name: str, value) -> np.ndarray:
    try:
        v = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise StabilityInputError(f"{name} must be 3 numbers [m], got {value!r}") from None
    if v.size != 3 or not np.all(np.isfinite(v)):
        raise StabilityInputError(f"{name} must be 3 finite numbers [m], got {value!r}")
    v.setflags(write=False)
    return v


def _rotation(name: str, value) -> np.ndarray:
    try:
        R = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise StabilityInputError(f"{name} must be a 3x3 rotation matrix, got {value!r}") from None
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise StabilityInputError(f"{name} must be a finite 3x3 rotation matrix (shape {R.shape})")
    if np.max(np.abs(R.T @ R - np.eye(3))) > 1e-6 or np.linalg.det(R) < 0:
        raise StabilityInputError(f"{name} must be orthonormal with det +1 (a proper rotation), within 1e-6")
    return R


@dataclass(frozen=True, eq=False)
class Tractor:
    """An empty tractor placed in the hitch's tractor frame (SI: kg, m).

    ``mass`` is the empty mass T_L [kg]; ``centre_of_mass``, ``rear_axle`` (rear-axle centre),
    ``front_axle_pivot`` and ``front_ballast_point`` (CoG of a front ballast on the front
    weight carrier) are (3,) points in the tractor frame [m]; ``ground_z`` is the ground
    plane's z (= -pivot_height) [m].  The pivot must lie one wheelbase ahead of the rear axle,
    on or above the ground, and the ballast CoG ahead of the front axle.
    """

    name: str
    mass: float
    centre_of_mass: np.ndarray
    wheelbase: float
    rear_track: float
    rear_axle: np.ndarray
    front_axle_pivot: np.ndarray
    front_ballast_point: np.ndarray
    ground_z: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "mass", _scalar("mass", self.mass, 0.0, 50_000.0, open_lo=True))
        object.__setattr__(self, "wheelbase", _scalar("wheelbase", self.wheelbase, 0.0, 10.0, open_lo=True))
        object.__setattr__(self, "rear_track", _scalar("rear_track", self.rear_track, 0.0, 5.0, open_lo=True))
        object.__setattr__(self, "ground_z", _scalar("ground_z", self.ground_z, -5.0, 5.0))
        for n in ("centre_of_mass", "rear_axle", "front_axle_pivot", "front_ballast_point"):
            object.__setattr__(self, n, _vector3(n, getattr(self, n)))
        if abs(self.front_axle_pivot[1] - (self.rear_axle[1] - self.wheelbase)) > 1e-6:
            raise StabilityInputError(
                f"front_axle_pivot y = {self.front_axle_pivot[1]} must equal rear_axle y - wheelbase "
                f"= {self.rear_axle[1] - self.wheelbase}"
            )
        if self.front_axle_pivot[2] < self.ground_z:
            raise StabilityInputError(f"front_axle_pivot z = {self.front_axle_pivot[2]} lies below ground_z")
        if self.front_ballast_arm < 0:
            raise StabilityInputError("front_ballast_point must lie ahead of (or at) the front axle (y <= pivot y)")

    @property
    def rear_left_contact(self) -> np.ndarray:
        """Left rear tyre contact (3,) [m], below the rear-axle centre."""
        return np.array([self.rear_track / 2, self.rear_axle[1], self.ground_z])

    @property
    def rear_right_contact(self) -> np.ndarray:
        """Right rear tyre contact (3,) [m]."""
        return np.array([-self.rear_track / 2, self.rear_axle[1], self.ground_z])

    @property
    def support_vertices(self) -> np.ndarray:
        """Support triangle (3, 3), rows: rear-left contact, rear-right contact, front-axle pivot [m]."""
        return np.vstack([self.rear_left_contact, self.rear_right_contact, self.front_axle_pivot])

    @property
    def empty_weight(self) -> float:
        """Weight of the empty tractor [N] (standard gravity)."""
        return self.mass * STANDARD_GRAVITY

    @property
    def empty_front_axle_mass(self) -> float:
        """T_V [kg]: the mass the front axle carries for the empty tractor on level ground."""
        return self.mass * (self.rear_axle[1] - self.centre_of_mass[1]) / self.wheelbase

    @property
    def front_ballast_arm(self) -> float:
        """a [m]: longitudinal distance front-axle centre -> front-ballast CoG (ballast manuals)."""
        return float(self.front_axle_pivot[1] - self.front_ballast_point[1])


@dataclass(frozen=True)
class ImplementRecord:
    """A mounted implement: ISO 730 category, mass [kg], CoM (x_i, y_i, z_i) in the implement frame [m]."""

    name: str
    category: str
    mass: float
    centre_of_mass: tuple[float, float, float]
    description: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise StabilityInputError(f"name must be a non-empty string, got {self.name!r}")
        if self.category not in ISO730_CATEGORIES:
            raise StabilityInputError(
                f"category = {self.category!r} is not an ISO 730 category; allowed: {', '.join(ISO730_CATEGORIES)}"
            )
        object.__setattr__(self, "mass", _scalar("mass", self.mass, 0.0, 20_000.0, open_lo=True))
        com = _vector3("centre_of_mass", self.centre_of_mass)
        object.__setattr__(self, "centre_of_mass", (float(com[0]), float(com[1]), float(com[2])))


# ----------------------------------------------------------------------------- schema


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class CentreOfMassSpec(_Strict):
    """Tractor CoM: x lateral (+ left), y from the lower-link pivots (+ rear), height above ground [m]."""

    x: float = Field(json_schema_extra={"unit": "m"}, ge=-1.0, le=1.0)
    y: float = Field(json_schema_extra={"unit": "m"}, ge=-8.0, le=2.0)
    height: float = Field(json_schema_extra={"unit": "m"}, gt=0.0, le=4.0)


class RearAxleSpec(_Strict):
    """Rear-axle centre: y from the lower-link pivots (+ rear), height above ground [m]."""

    y: float = Field(json_schema_extra={"unit": "m"}, ge=-3.0, le=1.0)
    height: float = Field(json_schema_extra={"unit": "m"}, gt=0.0, le=3.0)


class FrontAxlePivotSpec(_Strict):
    """Front-axle oscillation pivot: height above ground [m] (on the centre line, at the axle)."""

    height: float = Field(json_schema_extra={"unit": "m"}, gt=0.0, le=3.0)


class FrontBallastSpec(_Strict):
    """Front ballast CoG: ``arm`` a ahead of the front axle, ``height`` above ground [m]."""

    arm: float = Field(json_schema_extra={"unit": "m"}, ge=0.0, le=3.0)
    height: float = Field(json_schema_extra={"unit": "m"}, gt=0.0, le=3.0)


class TractorSpec(_Strict):
    """The empty tractor. ``mass`` T_L and ``front_axle_mass_empty`` T_V in kg, lengths in m."""

    #: from TRACTOR_MASS_MIN_KG (no lighter machine carries a three-point hitch; a mass typed in tonnes, 6.0, is
    #: named as such) to 50 t
    mass: float = Field(json_schema_extra={"unit": "kg"}, ge=TRACTOR_MASS_MIN_KG, le=50_000.0)
    #: weighbridge reading of the empty front axle; if given it must match the CoM within 1 % of mass
    front_axle_mass_empty: float | None = Field(json_schema_extra={"unit": "kg"}, default=None, gt=0.0, le=50_000.0)
    centre_of_mass: CentreOfMassSpec
    wheelbase: float = Field(json_schema_extra={"unit": "m"}, gt=0.5, le=6.0)
    rear_track: float = Field(json_schema_extra={"unit": "m"}, gt=0.3, le=4.0)
    rear_axle: RearAxleSpec
    front_axle_pivot: FrontAxlePivotSpec
    front_ballast: FrontBallastSpec

    @model_validator(mode="after")
    def _check(self):
        y_r, y_f = self.rear_axle.y, self.rear_axle.y - self.wheelbase
        com = self.centre_of_mass
        if not y_f < com.y < y_r:
            raise TractorProfileError(
                f"centre_of_mass.y = {com.y} must lie between the front axle (y = {y_f:.3f}) "
                f"and the rear axle (y = {y_r:.3f})"
            )
        half = 0.5 * self.rear_track * (com.y - y_f) / self.wheelbase  # triangle half-width at com.y
        if abs(com.x) >= half:
            raise TractorProfileError(
                f"centre_of_mass.x = {com.x} puts the empty tractor outside its support triangle "
                f"(|x| must be < {half:.3f} m at y = {com.y})"
            )
        if self.front_axle_mass_empty is not None:
            implied = self.mass * (y_r - com.y) / self.wheelbase
            front = self.front_axle_mass_empty
            if not front < self.mass:  # no centre of mass between the axles matches it: say so, not a y outside them
                raise TractorProfileError(
                    f"front_axle_mass_empty = {front} kg must be less than the tractor's mass = {self.mass} kg (the "
                    f"front axle carries part of it; this centre_of_mass.y implies {implied:.1f} kg)"
                )
            if front * 1000.0 < self.mass and abs(implied - front * 1000.0) <= 0.01 * self.mass:
                raise TractorProfileError(
                    f"front_axle_mass_empty = {front} kg disagrees with centre_of_mass.y = {com.y} (which implies "
                    f"{implied:.1f} kg); did you mean t? {front:.6g} t = {front * 1000.0:.6g} kg"
                )
            if abs(implied - front) > 0.01 * self.mass:
                y_match = y_r - self.front_axle_mass_empty * self.wheelbase / self.mass
                raise TractorProfileError(
                    f"front_axle_mass_empty = {self.front_axle_mass_empty} kg disagrees with centre_of_mass.y = "
                    f"{com.y} (which implies {implied:.1f} kg; allowed difference 1 % of mass). "
                    f"centre_of_mass.y = {y_match:.4f} would match"
                )
        return self


class ImplementSpec(_Strict):
    """An implement record: ISO 730 category, mass [kg], CoM [x_i, y_i, z_i] in the implement frame [m]."""

    category: Category
    mass: float = Field(json_schema_extra={"unit": "kg"}, gt=IMPLEMENT_MASS_MIN_KG, le=IMPLEMENT_MASS_MAX_KG)
    centre_of_mass: tuple[float, float, float]
    description: str = ""

    @field_validator("centre_of_mass", mode="before")
    @classmethod
    def _com_three(cls, v):
        """Three numbers, said so (two gave pydantic's "centre_of_mass.2 …: Field required": a user trial)."""
        if not isinstance(v, (list, tuple)) or len(v) != 3:
            raise TractorProfileError(f"must be 3 numbers [x_i, y_i, z_i] in the implement frame [m], got {v!r}")
        return tuple(v)  # (strict validation takes a tuple, not the list a JSON array became)

    @field_validator("centre_of_mass")
    @classmethod
    def _com(cls, v):
        for axis, c in zip(("x_i", "y_i", "z_i"), v, strict=True):
            if abs(c) > 10.0:  # with the mm reading a coordinate in mm gets elsewhere (a user trial: 1600 had none)
                raise TractorProfileError(f"{axis} = {c:g} m must lie within ±10 m" + unit_hint(c, -10.0, 10.0, "m"))
        return v


class TractorProfileSpec(_Strict):
    schema_version: Literal[1]
    name: str = Field(min_length=1, max_length=80)
    description: str = ""
    tractor: TractorSpec
    implements: dict[str, ImplementSpec] = Field(default_factory=dict)


def build_tractor(spec: TractorSpec, pivot_height: float, name: str = "tractor") -> Tractor:
    """Place a ground-referenced :class:`TractorSpec` in the hitch frame.

    ``pivot_height`` [m] is the lower-link pivots' height above ground (hitch profile
    ``geometry.pivot_height``); every height h becomes z = h - pivot_height.
    """
    h = _scalar("pivot_height", pivot_height, 0.0, 3.0, open_lo=True)
    y_r = spec.rear_axle.y
    y_f = y_r - spec.wheelbase
    return Tractor(
        name=name,
        mass=spec.mass,
        centre_of_mass=np.array([spec.centre_of_mass.x, spec.centre_of_mass.y, spec.centre_of_mass.height - h]),
        wheelbase=spec.wheelbase,
        rear_track=spec.rear_track,
        rear_axle=np.array([0.0, y_r, spec.rear_axle.height - h]),
        front_axle_pivot=np.array([0.0, y_f, spec.front_axle_pivot.height - h]),
        front_ballast_point=np.array([0.0, y_f - spec.front_ballast.arm, spec.front_ballast.height - h]),
        ground_z=-h,
    )


@dataclass(frozen=True)
class TractorProfile:
    """A validated tractor profile: the tractor spec and its implement records by name."""

    name: str
    description: str
    spec: TractorSpec
    implements: Mapping[str, ImplementRecord]

    def tractor(self, pivot_height: float) -> Tractor:
        """The tractor in the hitch frame for a hitch whose lower-link pivots are ``pivot_height`` [m] high."""
        return build_tractor(self.spec, pivot_height, name=self.name)

    def implement(self, name: str) -> ImplementRecord:
        try:
            return self.implements[name]
        except KeyError:
            raise TractorProfileError(
                f"implement {name!r} is not in tractor profile {self.name!r}; allowed: {', '.join(self.implements)}"
            ) from None


def tractor_profile_from_dict(data: dict, source: str = "<dict>") -> TractorProfile:
    """Validate a tractor profile given as a dictionary (as parsed from TOML): strictly, as JSON values
    (a number must be a number: ``true`` or ``"7500"`` for a mass is refused)."""
    try:
        text = json.dumps(data)
    except (TypeError, ValueError) as exc:  # a value JSON cannot hold (a TOML date)
        raise TractorProfileError(f"invalid tractor profile {source}: {exc}") from None
    try:
        spec = TractorProfileSpec.model_validate_json(text, strict=True)
    except ValidationError as exc:
        raise TractorProfileError(format_validation_error("tractor profile", source, exc, TractorProfileSpec)) from None
    records = {
        n: ImplementRecord(n, s.category, s.mass, s.centre_of_mass, s.description) for n, s in spec.implements.items()
    }
    return TractorProfile(spec.name, spec.description, spec.tractor, MappingProxyType(records))


def load_tractor_profile(name_or_path: str | Path = "tractor-6t") -> TractorProfile:
    """Load a tractor profile by built-in name (``planner/profiles/tractors/<name>.toml``) or file path."""
    source, data = read_profile(name_or_path, subfolder="tractors", kind="tractor profile", error=TractorProfileError)
    return tractor_profile_from_dict(data, source=source)
