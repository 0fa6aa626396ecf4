"""Field runs of the twin: a soil-engaging implement driven over a terrain scenario.

A field file (TOML, ``schema_version = 1``, strict pydantic schema as :mod:`bridge.sim.scenario`:
unknown keys, wrong types, NaN/inf and out-of-range values are refused with the field named)
names a terrain scenario (a built-in name or a path relative to the field file) for the ground,
the speed and the tractor, and adds the implement, the soil and the draft pins. Built-in fields
live in ``bridge/sim/scenarios/fields/`` (outside the terrain scenarios' list).

Sections (SI units; the names carry them)::

    name, description, scenario (terrain scenario name or .toml path)
    [implement]  kind (chisel_plow_straight_point | field_cultivator_primary |
                 field_cultivator_secondary | moldboard_plow), width, texture, working_depth_m,
                 vertical_ratio
    [soil]       variation, patch_length_m, length_m, blend_m, seed
    [traction]   cone_index_pa, section_width_m, diameter_m, section_height_m, deflection_m,
                 wheel_load_n, wheels, transfer_ratio
    [draft_pins] noise_rms_n, tau_s, resolution_n, seed, nominal_force_n

Working depth and undulation. With the hitch held (position control) the tool tip stays
``working_depth_m`` below the tractor's contact plane; the ground under the implement moves
relative to that plane as the tractor pitches over the undulation
(:meth:`~bridge.sim.terrain.TerrainTwin.implement_ground_z`), so the depth is
``implement_ground_z(t) - tip_z`` with ``tip_z = -working_depth_m`` unless the caller gives the
tip height from the hitch pose. The scenario's speed is the true travel speed; the slip says how
much faster the driven wheels turn (wheel speed = v / (1 - slip)).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from bridge.isobus.j1939 import Switch
from bridge.isobus.messages import RearHitchStatus
from bridge.sim.draft_sensor import DraftPinConfig, DraftPinError, DraftPins, DraftReading, rear_hitch_status
from bridge.sim.scenario import Scenario, ScenarioError, load_scenario, read_named_toml, toml_names
from bridge.sim.soil import (
    CHISEL_PLOW_STRAIGHT_POINT,
    FIELD_CULTIVATOR_PRIMARY,
    FIELD_CULTIVATOR_SECONDARY,
    MOLDBOARD_PLOW,
    D497Coefficients,
    Implement,
    SoilError,
    SoilField,
    TractionParams,
    wheel_slip,
)
from planner.errors import HitchInputError
from planner.profiles.loader import format_validation_error

__all__ = [
    "FieldDraft",
    "IMPLEMENT_KINDS",
    "FieldError",
    "FieldRun",
    "FieldSample",
    "FieldSetup",
    "builtin_fields",
    "field_from_dict",
    "load_field",
]

IMPLEMENT_KINDS: dict[str, D497Coefficients] = {
    "chisel_plow_straight_point": CHISEL_PLOW_STRAIGHT_POINT,
    "field_cultivator_primary": FIELD_CULTIVATOR_PRIMARY,
    "field_cultivator_secondary": FIELD_CULTIVATOR_SECONDARY,
    "moldboard_plow": MOLDBOARD_PLOW,
}
"""The D497 Table 1 rows a field file can name."""


class FieldError(HitchInputError):
    """A field file or field-run input that cannot be used; the message names the field and range."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


class _ImplementSpec(_Strict):
    kind: Literal[
        "chisel_plow_straight_point", "field_cultivator_primary", "field_cultivator_secondary", "moldboard_plow"
    ]
    width: float = Field(gt=0.0, le=100.0)
    texture: Literal["fine", "medium", "coarse"] = "medium"
    working_depth_m: float = Field(ge=0.0, le=0.6)
    vertical_ratio: float = Field(default=0.3, ge=0.0, le=1.0)


class _SoilSpec(_Strict):
    variation: float = Field(default=0.3, ge=0.0, le=0.9)
    patch_length_m: float = Field(default=20.0, ge=0.5, le=1000.0)
    length_m: float = Field(default=1000.0, ge=0.5, le=100_000.0)
    blend_m: float = Field(default=2.0, ge=0.0, le=1000.0)
    seed: int = Field(default=0, ge=0, lt=2**32)


class _TractionSpec(_Strict):
    cone_index_pa: float = Field(default=1.2e6, ge=5.0e4, le=5.0e6)
    section_width_m: float = Field(default=0.65, ge=0.1, le=1.5)
    diameter_m: float = Field(default=1.85, ge=0.3, le=3.0)
    section_height_m: float = Field(default=0.42, ge=0.05, le=1.0)
    deflection_m: float = Field(default=0.07, ge=0.0, le=1.0)
    wheel_load_n: float = Field(default=6000.0 * 0.6 * 9.80665, gt=0.0, le=1.0e6)
    wheels: int = Field(default=2, ge=1, le=8)
    transfer_ratio: float = Field(default=0.2, ge=0.0, le=1.0)


class _PinsSpec(_Strict):
    noise_rms_n: float = Field(default=50.0, ge=0.0, le=10_000.0)
    tau_s: float = Field(default=0.1, ge=0.0, le=10.0)
    resolution_n: float = Field(default=10.0, ge=0.0, le=1000.0)
    seed: int = Field(default=0, ge=0, lt=2**32)
    nominal_force_n: float = Field(default=40_000.0, gt=0.0, le=1.0e6)


class _FieldSpec(_Strict):
    schema_version: Literal[1]
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = Field(default="", max_length=500)
    scenario: str = Field(min_length=1, max_length=300)
    implement: _ImplementSpec
    soil: _SoilSpec = Field(default_factory=_SoilSpec)
    traction: _TractionSpec = Field(default_factory=_TractionSpec)
    draft_pins: _PinsSpec = Field(default_factory=_PinsSpec)


@dataclass(frozen=True)
class FieldSetup:
    """A validated field: the terrain scenario and what the implement meets in it."""

    name: str
    description: str
    scenario: Scenario
    implement: Implement
    working_depth_m: float
    soil: SoilField
    traction: TractionParams
    pins: DraftPinConfig
    nominal_force_n: float
    source: str


@dataclass(frozen=True)
class FieldSample:
    """One step of a field run (SI units).

    Attributes:
        t, distance_m, speed_m_s: time, travelled distance and travel speed.
        depth_m: the tool's working depth (0 when out of the soil).
        resistance: the soil patch factor.
        draft_n, vertical_force_n: the true draft and the downward soil force on the lower links.
        slip: travel reduction of the driven wheels (1.0 when ``stalled``).
        stalled: the draft exceeds the tractive capacity.
        measured: the draft pins' reading; ``status``: the rear hitch status message sent.
    """

    t: float
    distance_m: float
    speed_m_s: float
    depth_m: float
    resistance: float
    draft_n: float
    vertical_force_n: float
    slip: float
    stalled: bool
    measured: DraftReading
    status: RearHitchStatus


class FieldRun:
    """A field setup stepped in simulated time (the draft pins keep their filter state)."""

    def __init__(self, setup: FieldSetup) -> None:
        self._setup = setup
        self._pins = DraftPins(setup.pins)

    @property
    def setup(self) -> FieldSetup:
        return self._setup

    def step(self, t: float, *, tip_z_m: float | None = None, position: float | None = None) -> FieldSample:
        """The implement at time ``t`` [s]; ``tip_z_m`` the tool tip's height above the tractor's
        contact plane [m] (default ``-working_depth_m``), ``position`` the hitch position 0..1 to report."""
        su = self._setup
        twin = su.scenario.twin
        try:
            tip = -su.working_depth_m if tip_z_m is None else float(tip_z_m)
            if not -1.0 <= tip <= 3.0:
                raise FieldError(f"tip_z_m = {tip_z_m!r} is outside the allowed range [-1, 3]")
            depth = max(0.0, twin.implement_ground_z(t) - tip)
            s = twin.distance_m(t)
            v = twin.speed.speed_m_s(t)
            r = su.soil.resistance(s - twin.implement_behind_m)
            draft = su.implement.draft_n(v, min(depth, 1.0), r)
            fv = su.implement.vertical_force_n(draft)
            try:
                slip, stalled = wheel_slip(su.traction, draft, fv), False
            except SoilError:
                if draft <= 0.0:
                    raise
                slip, stalled = 1.0, True
            reading = self._pins.measure(t, draft)
            status = rear_hitch_status(
                reading.draft_n,
                nominal_force_n=su.nominal_force_n,
                position=position,
                in_work=Switch.ON if depth > 0.0 else Switch.OFF,
            )
        except (SoilError, DraftPinError) as exc:
            raise FieldError(f"field {su.name}: {exc}") from None
        return FieldSample(t, s, v, depth, r, draft, fv, slip, stalled, reading, status)


def field_from_dict(data: Any, *, source: str = "<dict>", base: Traversable | Path | None = None) -> FieldSetup:
    """Validate parsed TOML ``data``; a scenario path is relative to ``base`` (default: the working folder)."""
    try:
        spec = _FieldSpec.model_validate(data)
    except ValidationError as err:
        raise FieldError(format_validation_error("field", source, err, _FieldSpec)) from None
    root: Traversable | Path = Path(".") if base is None else base
    ref = spec.scenario
    try:
        if ref.endswith(".toml"):
            where = root / ref
            if not isinstance(where, Path):
                where = Path(str(where))
            scenario = load_scenario(where)
        else:
            scenario = load_scenario(ref)
    except ScenarioError as exc:
        raise FieldError(f"field {source}: scenario = {ref!r}: {exc}") from None
    im, so, tr, pi = spec.implement, spec.soil, spec.traction, spec.draft_pins
    try:
        implement = Implement(IMPLEMENT_KINDS[im.kind], im.width, im.texture, im.vertical_ratio)
        soil = SoilField(so.variation, so.patch_length_m, so.length_m, so.blend_m, so.seed)
        traction = TractionParams(
            tr.cone_index_pa,
            tr.section_width_m,
            tr.diameter_m,
            tr.section_height_m,
            tr.deflection_m,
            tr.wheel_load_n,
            tr.wheels,
            tr.transfer_ratio,
        )
        pins = DraftPinConfig(pi.noise_rms_n, pi.tau_s, pi.resolution_n, pi.seed)
    except (SoilError, DraftPinError) as exc:
        raise FieldError(f"field {source}: {exc}") from None
    return FieldSetup(
        spec.name,
        spec.description,
        scenario,
        implement,
        im.working_depth_m,
        soil,
        traction,
        pins,
        pi.nominal_force_n,
        source,
    )


def _builtin_folder() -> Traversable:
    return resources.files("bridge.sim") / "scenarios" / "fields"


def builtin_fields() -> list[str]:
    """Names of the fields shipped in ``bridge/sim/scenarios/fields/``."""
    return toml_names(_builtin_folder())


def load_field(name_or_path: str | Path) -> FieldSetup:
    """A field from a ``.toml`` path or a built-in name."""
    data, where, base = read_named_toml(name_or_path, _builtin_folder(), "field", FieldError)
    return field_from_dict(data, source=str(where), base=base)


class FieldDraft:
    """The ECU node's draft source (:class:`bridge.sim.can_node.DraftSource`): the field run stepped
    with the tool tip's true height when the hitch status is due; keeps the latest sample."""

    def __init__(self, run: FieldRun, tip_z: Callable[[], float], *, lost_at_s: float | None = None) -> None:
        self.run = run
        self._tip_z = tip_z
        self.lost_at_s = lost_at_s
        self.last: FieldSample | None = None

    def __call__(self, now_s: float) -> RearHitchStatus | None:
        sample = self.run.step(now_s, tip_z_m=min(3.0, max(-1.0, self._tip_z())))
        self.last = sample
        if self.lost_at_s is not None and now_s >= self.lost_at_s:
            return replace(sample.status, draft_n=None, nominal_lower_link_force=None)
        return sample.status
