"""Geometry profiles: loading and validating hitch descriptions from TOML.

A profile holds every number the model needs, in SI units (m, rad, s). The schema
is strict: unknown keys, wrong types and values outside their physical range are
rejected with a :class:`ProfileError` whose message names the field, the value and
what is allowed.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from planner.errors import HitchInputError, unit_hint
from planner.profiles.loader import (
    ProfileError,
    builtin_profiles,
    check_profile_name,
    format_validation_error,
    read_profile,
)

__all__ = [
    "ProfileError",
    "Profile",
    "ActuatorSpec",
    "LiftSpec",
    "CylinderSpec",
    "Category",
    "ActuatorStops",
    "CountApproachSettings",
    "FinalApproach",
    "PlayLag",
    "load_profile",
    "available_profiles",
    "profile_from_dict",
    "tractor_profile_for",
    "write_profile_text",
    "THESIS_CONTROLLER_A",
]

ACTUATORS = ("lift", "tilt", "top", "left", "right")
BOX_KEYS = ("x", "z", "roll", "pitch")


#: Tuning parameter a of (thesis 2.57) used on the thesis's machine (thesis §3.1).
THESIS_CONTROLLER_A = 0.581


class _Strict(BaseModel):
    # NaN and infinity are refused field by field ("geometry.lift_arm_length = nan: Input should be a finite number
    # (allowed: > 0 and <= 3 m)"), not by the first bound they fail ("Input should be less than or equal to 3")
    model_config = ConfigDict(extra="forbid", frozen=True, strict=False, allow_inf_nan=False)


#: the fewest AD counts a sensor may read its stroke over (the ECU keeps 2 counts of end-stop margin at each
#: end, and a coarser reading cannot hold a pose; the thesis's sensors read 229..891 counts, table 3-1)
MIN_COUNT_SPAN = 16

#: the largest |bound| of a workspace box's x and z [m]: no three-point hitch moves its implement further
BOX_LENGTH_MAX_M = 2.0

#: the largest span and mast height of an implement category [m]
CATEGORY_LENGTH_MAX_M = 2.0

#: the largest |coordinate| of a geometry point [m]
COORDINATE_MAX_M = 5.0

#: the nearest the sway limiters' tractor point may lie to its lower-link pivot [m]: a limiter anchored on the
#: pivot has the same length at every sway (the bracket's distance from the pivot) and cannot hold the link;
#: nearer than a tape measure can tell apart from the pivot is on it
LIMITER_POINT_MIN_DISTANCE_M = 0.001


def _interval(name: str, value: tuple[float, float], *, angle: bool) -> tuple[float, float]:
    lo, hi = value
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ProfileError(f"{name} bounds must be finite numbers")
    if not lo < hi:
        raise ProfileError(f"{name} needs min < max (got [{lo}, {hi}])")
    if angle and (abs(lo) > math.pi or abs(hi) > math.pi):
        raise ProfileError(f"{name} bounds are angles in radians and must lie within ±π")
    return value


def _box_length(name: str, value: tuple[float, float]) -> None:
    """A box's x or z bounds [m] within ±BOX_LENGTH_MAX_M (millimetres are named)."""
    m = BOX_LENGTH_MAX_M
    for v in value:
        if abs(v) > m:
            raise ProfileError(
                f"{name} = [{value[0]}, {value[1]}]: bounds are in m and must lie within ±{m:g} m"
                + unit_hint(v, -m, m, "m")
            )


class Box(_Strict):
    """An axis-aligned box over the controlled DOF: x, z [m]; roll, pitch [rad]."""

    x: tuple[float, float]
    z: tuple[float, float]
    roll: tuple[float, float]
    pitch: tuple[float, float]

    @model_validator(mode="after")
    def _check(self):
        for k in BOX_KEYS:
            _interval(k, getattr(self, k), angle=k in ("roll", "pitch"))
        for k in ("x", "z"):
            _box_length(k, getattr(self, k))
        return self

    def as_dict(self) -> dict[str, tuple[float, float]]:
        return {k: tuple(getattr(self, k)) for k in BOX_KEYS}


#: the largest length of a geometry field [m]
_FIELD_MAX_M = 3.0


class Geometry(_Strict):
    lower_link_pivot_span: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=_FIELD_MAX_M)
    lower_link_length: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=_FIELD_MAX_M)
    lift_rod_attachment: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=_FIELD_MAX_M)
    limiter_bracket_position: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=_FIELD_MAX_M)
    limiter_bracket_offset: float = Field(json_schema_extra={"unit": "m"}, ge=0, le=1.0)
    fixed_lift_rod_length: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=3.0)
    lift_arm_length: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=3.0)
    lift_arm_pivot: tuple[float, float, float]
    top_link_tractor_point: tuple[float, float, float]
    limiter_tractor_point: tuple[float, float, float]
    pivot_height: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=3.0)

    @model_validator(mode="after")
    def _check(self):
        m = COORDINATE_MAX_M
        for name in ("lift_arm_pivot", "top_link_tractor_point", "limiter_tractor_point"):
            v = getattr(self, name)
            if not all(math.isfinite(c) and abs(c) <= m for c in v):
                worst = max(v, key=lambda c: abs(c) if math.isfinite(c) else math.inf)
                raise ProfileError(
                    f"{name} = [{', '.join(f'{c:g}' for c in v)}]: coordinates are in m and must be finite numbers "
                    f"within ±{m:g} m" + unit_hint(worst, -m, m, "m")
                )
        c = self.limiter_tractor_point
        if math.hypot(*c) < LIMITER_POINT_MIN_DISTANCE_M:
            rb = math.hypot(self.limiter_bracket_position, self.limiter_bracket_offset)
            raise ProfileError(
                f"limiter_tractor_point = [{', '.join(f'{x:g}' for x in c)}] m lies on the lower-link pivot (it is "
                f"relative to that side's pivot, {math.hypot(*c):.3g} m from it): a sway limiter anchored there has "
                f"the same length at every sway (the bracket's distance from the pivot, {rb:.4g} m, from "
                "limiter_bracket_position and limiter_bracket_offset) and cannot hold the lower link; allowed: at "
                f"least {LIMITER_POINT_MIN_DISTANCE_M:g} m from the pivot (x outward: the thesis profile's 0.1487 m)"
            )
        self._check_points_on_link()
        return self

    def _check_points_on_link(self) -> None:
        """The lift-rod attachment and the limiter bracket lie on the lower link (measured from its pivot, short
        of its end), else a ProfileError naming the fields, their values and the range of each (the others as
        given): a short lower_link_length was refused as "lift_rod_attachment must lie on the lower link"."""
        length, on_link = self.lower_link_length, ("lift_rod_attachment", "limiter_bracket_position")
        beyond = [n for n in on_link if getattr(self, n) >= length]
        if not beyond:
            return
        m = _FIELD_MAX_M
        given = " and ".join(f"{n} = {getattr(self, n):g} m" for n in beyond)
        farthest = max(getattr(self, n) for n in on_link)
        longer = f"lower_link_length must be within ({farthest:g}, {m:g}] m" if farthest < m else ""
        shorter = f"{' and '.join(beyond)} within (0, {length:g}) m"
        raise ProfileError(
            f"{given} {'lie' if len(beyond) > 1 else 'lies'} beyond the end of the lower link, lower_link_length = "
            f"{length:g} m (points on it are measured along it from its pivot): with the other fields as given, "
            + (f"{longer}, or {shorter}" if longer else f"{' and '.join(beyond)} must be within (0, {length:g}) m")
        )


class Category(_Strict):
    """ISO 730 implement category: lower hitch span (inner faces, as in the standard) and mast height [m]."""

    span: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=CATEGORY_LENGTH_MAX_M)
    mast_height: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=CATEGORY_LENGTH_MAX_M)


class Implement(_Strict):
    ball_centre_correction: float = Field(json_schema_extra={"unit": "m"}, ge=0, le=0.2)
    default_category: str
    categories: dict[str, Category]

    @model_validator(mode="after")
    def _check(self):
        if not self.categories:
            raise ProfileError("categories must list at least one ISO 730 category")
        if self.default_category not in self.categories:
            raise ProfileError(f"default_category {self.default_category!r} is not one of {sorted(self.categories)}")
        return self


class ActuatorSpec(_Strict):
    """One actuator: stroke, sensor calibration and identified valve dynamics (thesis 1.1).

    The stroke's unit and range are its kind's: :class:`LiftSpec` (an angle [rad]) or :class:`CylinderSpec`
    (a length [m]), as :class:`Actuators` takes them; this class checks what every kind shares."""

    #: the unit of ``min``, ``max`` and ``neutral`` ("" where the kind is not known)
    stroke_unit: ClassVar[str] = ""

    min: float
    max: float
    counts_min: int = Field(json_schema_extra={"unit": "counts"}, ge=0, le=1023)
    counts_max: int = Field(json_schema_extra={"unit": "counts"}, ge=0, le=1023)
    valve_multiplier: float = Field(gt=0, le=1.0)
    kv_pos: float = Field(gt=0, le=100.0)
    kv_neg: float = Field(gt=0, le=100.0)
    transport_delay: float = Field(json_schema_extra={"unit": "s"}, ge=0, le=2.0)
    time_constant: float = Field(json_schema_extra={"unit": "s"}, ge=0, le=2.0)
    min_flow: float = Field(ge=0, le=254)
    dead_zone: float = Field(ge=0, le=254)
    neutral: float | None = None

    @model_validator(mode="after")
    def _check(self):
        unit = f" {self.stroke_unit}" if self.stroke_unit else ""
        if not self.min < self.max:
            raise ProfileError(f"stroke needs min < max (got min = {self.min:g}{unit}, max = {self.max:g}{unit})")
        if self.counts_min >= self.counts_max:  # a reversed pair is not a span that is too short
            raise ProfileError(
                f"counts_min = {self.counts_min} must be below counts_max = {self.counts_max}: the sensor reads "
                f"counts_min at the stroke's min and counts_max at its max, at least {MIN_COUNT_SPAN} counts apart "
                f"(counts_max - counts_min >= {MIN_COUNT_SPAN})"
                + ("; these are reversed (swap them)" if self.counts_min > self.counts_max else "")
            )
        if self.counts_max - self.counts_min < MIN_COUNT_SPAN:
            raise ProfileError(
                f"counts_min ({self.counts_min}) .. counts_max ({self.counts_max}): a sensor must read its stroke "
                f"over at least {MIN_COUNT_SPAN} counts (counts_max - counts_min >= {MIN_COUNT_SPAN})"
            )
        if self.neutral is not None and not (self.min <= self.neutral <= self.max):
            hint = unit_hint(self.neutral, self.min, self.max, self.stroke_unit) if self.stroke_unit else ""
            raise ProfileError(
                f"neutral = {self.neutral:g}{unit} must lie within the stroke [min, max] = "
                f"[{self.min:g}, {self.max:g}]{unit}{hint}"
            )
        return self


#: the lift's stroke is its lift-arm angle θ_E [rad], within (-π/2, π/2) (the arm never passes the vertical)
_LiftStroke = Annotated[float, Field(json_schema_extra={"unit": "rad"}, gt=-math.pi / 2, lt=math.pi / 2)]
#: a cylinder's (tilt, top link, sway limiters) stroke is its length [m], within (0, 5]
_CylinderStroke = Annotated[float, Field(json_schema_extra={"unit": "m"}, gt=0.0, le=5.0)]


class LiftSpec(ActuatorSpec):
    """The lift: an :class:`ActuatorSpec` whose stroke (``min``, ``max``, ``neutral``) is an angle [rad] within
    (-π/2, π/2); a value out of range is named with its unit ("did you mean degrees? …")."""

    stroke_unit: ClassVar[str] = "rad"

    min: _LiftStroke
    max: _LiftStroke


class CylinderSpec(ActuatorSpec):
    """A cylinder (tilt, top link, sway limiter): an :class:`ActuatorSpec` whose stroke (``min``, ``max``,
    ``neutral``) is a length [m] within (0, 5]; a value out of range is named with its unit ("did you mean
    mm? …")."""

    stroke_unit: ClassVar[str] = "m"

    min: _CylinderStroke
    max: _CylinderStroke


class Actuators(_Strict):
    """The five actuators. Each stroke's range is checked field by field with its unit (``actuators.top.min =
    655: … (allowed: > 0 and <= 5 m; did you mean mm? …)``) before the checks between fields (min < max, the
    AD span, the neutral), so a stroke typed in mm is named as such, not as a neutral outside it."""

    lift: LiftSpec
    tilt: CylinderSpec
    top: CylinderSpec
    left: CylinderSpec
    right: CylinderSpec


class KeepOut(_Strict):
    """A sphere the top link (segment H–U) must stay clear of, e.g. the remote-hydraulics couplers."""

    name: str = Field(min_length=1, max_length=60)
    centre: tuple[float, float, float]
    radius: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=1.0)

    @field_validator("centre")
    @classmethod
    def _centre(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        """Within ±COORDINATE_MAX_M of the tractor frame's origin, as the geometry's points: a centre typed in mm
        (``[0, 300, 860]``) put the sphere hundreds of metres away and silently switched the keep-out off."""
        m = COORDINATE_MAX_M
        if not all(math.isfinite(c) and abs(c) <= m for c in v):
            worst = max(v, key=lambda c: abs(c) if math.isfinite(c) else math.inf)
            raise ProfileError(
                f"coordinates are in m (tractor frame) and must be finite numbers within ±{m:g} m"
                + unit_hint(worst, -m, m, "m")
            )
        return v


class Limits(_Strict):
    top_link_yaw_max: float = Field(json_schema_extra={"unit": "rad"}, gt=0, le=math.pi / 2)
    top_link_pitch_up_max: float = Field(json_schema_extra={"unit": "rad"}, gt=0, le=math.pi / 2)
    top_link_pitch_down_max: float = Field(json_schema_extra={"unit": "rad"}, gt=0, le=math.pi / 2)
    top_link_angle_reference: Literal["neutral", "horizontal"] = "neutral"
    ground_clearance: float = Field(json_schema_extra={"unit": "m"}, ge=-1.0, le=2.0)
    keep_out: list[KeepOut] = Field(default_factory=list)
    end_stop_zone: float = Field(default=0.05, ge=0.0, le=0.5)


class PlayLag(_Strict):
    """The implement's lag behind the mechanism after a rising final approach, per DOF [m, m, rad, rad]: the
    pin play taken up on one side (a dead band's half-width as the pose sees it). A fitted value
    (``hitch calibrate geometry`` from poses measured with their approach side), so it may be slightly
    negative within its noise."""

    x: float = Field(json_schema_extra={"unit": "m"}, ge=-0.005, le=0.01)
    z: float = Field(json_schema_extra={"unit": "m"}, ge=-0.005, le=0.01)
    roll: float = Field(json_schema_extra={"unit": "rad"}, ge=-0.01, le=0.02)
    pitch: float = Field(json_schema_extra={"unit": "rad"}, ge=-0.01, le=0.02)

    def vector(self) -> tuple[float, float, float, float]:
        """(x, z, roll, pitch) [m, m, rad, rad]."""
        return (self.x, self.z, self.roll, self.pitch)


class FinalApproach(_Strict):
    """How far below a goto's goal its last segment starts, per DOF [m, m, rad, rad] (0: no approach in that
    DOF): the move ends rising in every DOF, so pin play and the ECU's stop inside a count are taken up
    on the same side every time (:mod:`planner.trajectory.final_approach`). ``side = "above"``: the last
    segment starts that far above the goal and ends falling instead."""

    x: float = Field(json_schema_extra={"unit": "m"}, ge=0.0, le=0.05)
    z: float = Field(json_schema_extra={"unit": "m"}, ge=0.0, le=0.05)
    roll: float = Field(json_schema_extra={"unit": "rad"}, ge=0.0, le=0.1)
    pitch: float = Field(json_schema_extra={"unit": "rad"}, ge=0.0, le=0.1)
    side: Literal["below", "above"] = "below"
    #: how far the implement rests behind the mechanism after the approach (the pin play taken up), as
    #: ``hitch calibrate geometry`` identifies it; the planner aims the mechanism that far beyond each goal
    lag: PlayLag | None = None

    @model_validator(mode="after")
    def _check_lag(self):
        """An approach shorter than the play band (2·|lag|) may not take the play up from the other side:
        then the implement does not rest ``lag`` behind the mechanism and aiming by it is wrong."""
        if self.lag is None:
            return self
        bad = []
        for k, off, lag in zip(("x", "z", "roll", "pitch"), self.offset(), self.lag.vector(), strict=True):
            unit = "rad" if k in ("roll", "pitch") else "m"
            if off > 0 and off < 2.0 * abs(lag) - 1e-12:
                bad.append(
                    f"lag.{k} = {lag:.9g} {unit} needs an approach of at least the play band 2·|lag| = "
                    f"{2.0 * abs(lag):.9g} {unit}, but {k} = {off:.9g} {unit} (make {k} >= {2.0 * abs(lag):.9g} "
                    f"{unit}, and measure again with it, or lag.{k} within ±{off / 2.0:.9g} {unit})"
                )
        if bad:
            raise ProfileError(
                "; ".join(bad) + ": an approach shorter than the band may not take the play up, so the implement "
                "would not rest the lag behind the mechanism"
            )
        return self

    def offset(self) -> tuple[float, float, float, float]:
        """(x, z, roll, pitch) [m, m, rad, rad]: how far from the goal the last segment starts (unsigned)."""
        return (self.x, self.z, self.roll, self.pitch)

    @property
    def sign(self) -> float:
        """+1 when the approach ends rising (``side = "below"``), −1 when it ends falling."""
        return 1.0 if self.side == "below" else -1.0

    def rise(self) -> tuple[float, float, float, float]:
        """The approach's last segment, goal minus its start (x, z, roll, pitch) [m, m, rad, rad]: the offset,
        negative for ``side = "above"``."""
        return (self.sign * self.x, self.sign * self.z, self.sign * self.roll, self.sign * self.pitch)

    def aim_shift(self) -> tuple[float, float, float, float]:
        """How far beyond the goal the mechanism is aimed so the lagging implement rests on it: sign · lag in
        the DOF with an approach (x, z, roll, pitch) [m, m, rad, rad]; 0 without a lag."""
        lx, lz, lr, lp = self.lag_vector()
        return (self.sign * lx, self.sign * lz, self.sign * lr, self.sign * lp)

    def lag_vector(self) -> tuple[float, float, float, float]:
        """The lag (x, z, roll, pitch) [m, m, rad, rad] in the DOF with an approach; 0 elsewhere (and without one)."""
        if self.lag is None:
            return (0.0, 0.0, 0.0, 0.0)
        (lx, lz, lr, lp), (dx, dz, dr, dp) = self.lag.vector(), self.offset()
        return (lx if dx > 0 else 0.0, lz if dz > 0 else 0.0, lr if dr > 0 else 0.0, lp if dp > 0 else 0.0)


_StopList = Annotated[list[Annotated[float, Field(gt=-1.0, lt=1.0)]], Field(min_length=1, max_length=5)]


class ActuatorStops(_Strict):
    """Per actuator, where its piston stops inside a reference count after a back-off of 1, 2, … counts
    (1 to 5 values, each in (−1, 1)) [AD counts, piston − count]."""

    lift: _StopList
    tilt: _StopList
    top: _StopList
    left: _StopList
    right: _StopList

    def values(self) -> tuple[tuple[float, ...], ...]:
        """(lift, tilt, top, left, right), each the offsets for back-offs 1, 2, … [counts]."""
        return tuple(tuple(getattr(self, k)) for k in ACTUATORS)

    def first_only(self) -> ActuatorStops:
        """The same with each actuator's back-off of one count only."""
        return ActuatorStops(**{k: getattr(self, k)[:1] for k in ACTUATORS})


class CountApproachSettings(_Strict):
    """Where the ECU leaves each piston inside its reference count when it rises into it (``from_below``)
    and when it falls into it (``from_above``), after a back-off of 1, 2, … counts; a goto then ends on the
    count, side and back-off whose stop is nearest its exact goal (:mod:`planner.trajectory.count_approach`).
    ``keep_arrival_side``: with ``final_approach``, each actuator enters its count from the side the final
    approach moves it (so the pin play stays taken up on one side); False, or without a final approach:
    from either side."""

    from_below_counts: ActuatorStops
    from_above_counts: ActuatorStops
    keep_arrival_side: bool = True
    via_hold_s: float = Field(json_schema_extra={"unit": "s"}, default=0.6, gt=0.0, le=10.0)
    final_hold_s: float = Field(json_schema_extra={"unit": "s"}, default=0.6, gt=0.0, le=10.0)


class Motion(_Strict):
    """Motion limits derived from the valves.

    Actuator velocity limit = velocity_fraction × min(kv_pos, kv_neg) × 254 × valve_multiplier
    (AD counts/s, thesis tables 3-3, 3-4) converted to SI; acceleration limit = velocity
    limit / acceleration_time; jerk limit = acceleration limit / jerk_time.
    """

    velocity_fraction: float = Field(default=0.9, gt=0, le=1.0)
    acceleration_time: float = Field(json_schema_extra={"unit": "s"}, default=0.3, gt=0, le=10.0)
    jerk_time: float = Field(json_schema_extra={"unit": "s"}, default=0.15, gt=0, le=10.0)
    control_rate: float = Field(json_schema_extra={"unit": "Hz"}, default=50.0, ge=1.0, le=200.0)
    #: tuning a of the cylinder ECU's unit controllers (thesis 2.57), 0.581 on the thesis's machine (thesis §3.1);
    #: the planner needs it to invert the unit loops (feed-forward), the simulated ECU runs with it
    controller_a: float = Field(default=THESIS_CONTROLLER_A, gt=0, le=2.0)
    #: unidirectional final approach of every goto (None: gotos end straight from where they come)
    final_approach: FinalApproach | None = None
    #: each goto ends on the AD count and side whose stop inside the count is nearest the goal (None: off)
    count_approach: CountApproachSettings | None = None


#: a front ballast [kg] is 0 (none) or more than this: every value up to it could be typed in tonnes (5 t being the
#: heaviest) and is refused with the tonnes reading ("did you mean t? 0.9 t = 900 kg"; 0.9 was taken as 0.9 kg: a
#: user trial); no front ballast weighs 5 kg or less
FRONT_BALLAST_MIN_KG = 5.0


class Stability(_Strict):
    """Which tractor carries the hitch (a profile in planner/profiles/tractors/) and its front ballast [kg]."""

    tractor_profile: str = "tractor-6t"
    #: 0 (none) or (FRONT_BALLAST_MIN_KG, 5000] kg
    front_ballast: float = Field(json_schema_extra={"unit": "kg"}, default=0.0, ge=0.0, le=5000.0)
    #: slow-down factor when a margin falls below its caution threshold (free-gait source: 0.8)
    caution_speed_factor: float = Field(default=0.8, gt=0.0, le=1.0)
    #: how far ahead jog motion is evaluated [s] (free-gait source: about one second)
    jog_horizon: float = Field(json_schema_extra={"unit": "s"}, default=1.0, gt=0.0, le=5.0)

    @field_validator("front_ballast")
    @classmethod
    def _ballast(cls, v: float) -> float:
        if 0.0 < v <= FRONT_BALLAST_MIN_KG:  # the loader adds the range and "did you mean t?"
            raise ValueError(f"must be 0 (no ballast) or more than {FRONT_BALLAST_MIN_KG:g} kg")
        return v


class Workspace(_Strict):
    thesis_box: Box
    z_reference: Literal["neutral", "pivot"] = "neutral"
    #: restricted (operator-level) workspace per category, absolute in the tractor frame
    restricted: dict[str, Box] = Field(default_factory=dict)


class Profile(_Strict):
    """A hitch profile (``docs/profiles.md``; SI: m, rad, s): the geometry of the tractor's three-point linkage,
    the implement, the actuators (strokes, AD sensor scaling, speeds), the hard limits, the workspace, motion
    settings and the stability set-up. Load one with :func:`load_profile`; every field is validated and an
    error names the field, its value and the allowed range."""

    schema_version: Literal[1]
    name: str = Field(min_length=1, max_length=80)
    description: str = ""
    geometry: Geometry
    implement: Implement
    actuators: Actuators
    limits: Limits
    workspace: Workspace
    motion: Motion = Field(default_factory=Motion)
    stability: Stability = Field(default_factory=Stability)

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return check_profile_name(v)

    @model_validator(mode="after")
    def _check(self):
        unknown = sorted(set(self.workspace.restricted) - set(self.implement.categories))
        if unknown:
            raise ProfileError(
                f"workspace.restricted: no category {', '.join(map(repr, unknown))} in implement.categories "
                f"(allowed: {', '.join(self.implement.categories)})"
            )
        return self

    def category(self, name: str) -> Category:
        try:
            return self.implement.categories[name]
        except KeyError:
            text = "" if isinstance(name, str) else f" (a category is text: {str(name)!r}, not {type(name).__name__})"
            raise ProfileError(
                f"category {name!r} is not in profile {self.name!r}; allowed: {', '.join(self.implement.categories)}"
                + text
            ) from None

    def span(self, category: str) -> float:
        """Ball-centre lower hitch span [m]: the ISO 730 span plus the correction.

        This is the one place the +40 mm ball-centre correction (thesis §3.2) is applied.
        """
        return self.category(category).span + self.implement.ball_centre_correction

    def actuator(self, name: str) -> ActuatorSpec:
        return getattr(self.actuators, name)


def available_profiles() -> list[str]:
    """Names of the hitch profiles shipped with the package."""
    return builtin_profiles(None)


def load_profile(name_or_path: str | Path = "thesis-t132") -> Profile:
    """Load and validate a profile by built-in name or file path.

    ``stability.tractor_profile`` is a built-in tractor name or a path to a .toml file; a relative path
    is taken from the profile file's folder. The tractor profile is loaded here too, so a missing or
    invalid one is an error of this profile's field (not of the first stability check)."""
    source, data = read_profile(name_or_path, subfolder=None, kind="profile", error=ProfileError)
    prof = profile_from_dict(data, source=source)
    from_file = Path(name_or_path).suffix == ".toml" or Path(name_or_path).exists()
    return _with_tractor_profile(prof, Path(source).parent if from_file else None, source)


def _with_tractor_profile(prof: Profile, folder: Path | None, source: str) -> Profile:
    """``stability.tractor_profile`` resolved (a relative path from ``folder``, the profile file's) and read as
    TOML here; its schema is checked where the stability layer loads it (:mod:`planner.limits.tractor`)."""
    given = prof.stability.tractor_profile
    path = Path(given)
    resolved = given
    if folder is not None and not path.is_absolute() and _is_tractor_path(given):
        resolved = str(folder / path)
    try:
        read_profile(resolved, subfolder="tractors", kind="tractor profile", error=ProfileError)
    except HitchInputError as exc:
        raise ProfileError(f"profile {source}: stability.tractor_profile = {given!r}: {exc}") from None
    if resolved == given:
        return prof
    return prof.model_copy(update={"stability": prof.stability.model_copy(update={"tractor_profile": resolved})})


def _is_tractor_path(value: str) -> bool:
    """``stability.tractor_profile`` names a file (``.toml`` or with a folder), not a built-in tractor."""
    path = Path(value)
    return path.suffix == ".toml" or len(path.parts) > 1


def tractor_profile_for(value: str, out_folder: str | Path | None, *, relative_to: str | Path | None = None) -> str:
    """``stability.tractor_profile`` = ``value`` as written into a profile file in ``out_folder``.

    A built-in tractor name stays. A path, relative ones taken from ``relative_to`` (the folder of the file
    it was read from; None: the current folder, as a loaded :class:`Profile` holds it), is written relative to
    ``out_folder`` — the loader takes it from the written file's folder — or absolute when ``out_folder`` is
    None (text whose file is not known yet). Copying the value as it was made the written profile point at
    ``prof/prof/my-tractor.toml``."""
    if not _is_tractor_path(value):
        return value
    path = Path(value)
    if not path.is_absolute():
        path = Path(relative_to if relative_to is not None else ".") / path
    path = path.resolve()
    if out_folder is None:
        return str(path)
    return os.path.relpath(path, Path(out_folder).resolve())


def write_profile_text(
    path: str | Path, text: str, *, what: str = "profile", check: Callable[[Profile], object] | None = None
) -> Profile:
    """Write profile TOML ``text`` to ``path`` only if it loads there (:func:`load_profile`: the schema, the
    tractor profile taken from ``path``'s folder) and passes ``check`` (called with the profile loaded from the
    file; a :class:`HitchInputError` refuses it, e.g. a model that does not build); the loaded profile. Written
    to a file beside it first and renamed: a refused text leaves nothing behind (an old file at ``path`` stays
    as it was)."""
    p = Path(path)
    if p.suffix != ".toml":
        raise ProfileError(f"{what} file {p}: the name must end in .toml")
    tmp = p.with_name(f".{p.stem}.writing.toml")
    try:
        tmp.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ProfileError(f"{what} file {p}: cannot write it ({exc.strerror})") from None
    try:
        prof = load_profile(tmp)
        if check is not None:
            check(prof)
        os.replace(tmp, p)
    except HitchInputError as exc:
        raise ProfileError(f"{what} file {p} was not written: {str(exc).replace(str(tmp), str(p))}") from None
    except OSError as exc:
        raise ProfileError(f"{what} file {p}: cannot write it ({exc.strerror})") from None
    finally:
        tmp.unlink(missing_ok=True)
    return prof


def profile_from_dict(data: dict[str, Any], source: str = "<dict>") -> Profile:
    """Validate a profile given as a dictionary (as parsed from TOML).

    Strictly, as JSON values: a number must be a number (``true`` or ``"0.96"`` for a length is
    refused, where pydantic's lax mode read 1.0 and 0.96), an array may stand for a tuple."""
    try:
        text = json.dumps(data, allow_nan=True)
    except (TypeError, ValueError) as exc:  # a value JSON cannot hold (a TOML date, an object)
        raise ProfileError(f"invalid profile {source}: {exc}") from None
    try:
        return Profile.model_validate_json(text, strict=True)
    except ValidationError as exc:
        raise ProfileError(format_validation_error("profile", source, exc, Profile)) from None
