"""Scenario files of the terrain twin: TOML (terrain, speed, signals, duration) -> :class:`Scenario`.

A scenario is a TOML file (``schema_version = 1``) read with :mod:`tomllib` and validated by a
strict pydantic schema (as the planner's profiles: unknown keys, wrong types, NaN/inf and
out-of-range values are refused, every bad field named with its allowed range) into frozen
dataclasses (:class:`Scenario` holds a :class:`~bridge.sim.terrain.TerrainTwin`). Built-in
scenarios live in ``bridge/sim/scenarios/`` (``flat``, ``levelling``, ``guidance``, ``terrain``).

Sections (SI units; the names carry them)::

    name, description, duration_s (0 < d <= 3600)
    [tractor]   wheelbase_m, track_m, suspension ("rigid" | "oscillating"), implement_behind_m
    [speed]     constant_m_s (0..15)  or  csv = "file.csv" (columns time_s,speed_m_s)
    [terrain]   grade_rad, cross_slope_rad, [[terrain.undulation]] amplitude_m, wavelength_m,
                phase_rad, [[terrain.cross_slope_wave]] amplitude_rad, wavelength_m, phase_rad
                or csv = "file.csv" (columns distance_m,height_m[,cross_slope_rad])
    [signals]   row_offset_rms_m (default 0: no crop row; > 0 makes it a guidance job),
                row_wavelength_min_m, row_wavelength_max_m, row_noise_rms_m (default 0),
                row_rate_hz, seed, row_camera_ahead_m (0..20: the camera's look-ahead ahead of
                the implement; 0 = under it), ground_sensor_ahead_m (0..20: a look-ahead
                ground-distance sensor on the tractor ahead of the implement; 0 = none),
                ground_sensor_mount_height_m (0.1..3), ground_sensor_noise_rms_m (0..0.05)

CSV files (read with :mod:`csv`, paths relative to the TOML file) have a header row naming the
columns; errors give the file and the line number.
"""

from __future__ import annotations

import csv
import io
import math
import tomllib
from dataclasses import dataclass
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from bridge.sim.terrain import (
    CrossSlopeWave,
    GroundProfile,
    LookAheadGroundSensor,
    RowSignal,
    SampledGround,
    SineGround,
    SpeedProfile,
    TerrainError,
    TerrainTwin,
    TractorGeometry,
    Undulation,
)
from planner.errors import HitchInputError
from planner.profiles.loader import format_validation_error
from planner.textfile import csv_error_words, read_text_file

__all__ = ["SCHEMA_VERSION", "Scenario", "ScenarioError", "builtin_scenarios", "load_scenario", "scenario_from_dict"]

SCHEMA_VERSION = 1


class ScenarioError(HitchInputError):
    """A scenario file that cannot be used; the message names the field (or CSV line) and the allowed range."""


#: the steepest ground a scenario may describe, |Δheight / Δdistance| between two CSV rows or the sum of its
#: sines' slopes (1 = 45°): a tractor drives nothing steeper, and a step is a typing error (mm for m, a missing
#: decimal point)
MAX_TERRAIN_SLOPE = 1.0
#: at most this many sines per terrain list (undulation, cross_slope_wave): each is evaluated every twin tick
MAX_TERRAIN_WAVES = 64
#: the largest scenario CSV file [bytes]: a 51 MB file was read into 712 MB of memory (a field trial); 32 MiB
#: hold about 1.5 million rows of distance and height (an hour at 15 m/s every 4 cm)
MAX_CSV_BYTES = 32 * 2**20


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


class _TractorSpec(_Strict):
    wheelbase_m: float = Field(default=2.70, gt=0.5, le=10.0)
    track_m: float = Field(default=1.80, gt=0.5, le=5.0)
    suspension: Literal["rigid", "oscillating"] = "rigid"
    implement_behind_m: float = Field(default=1.2, ge=0.0, le=10.0)


class _SpeedSpec(_Strict):
    constant_m_s: float | None = Field(default=None, ge=0.0, le=15.0)
    csv: str | None = Field(default=None, min_length=1)

    @model_validator(mode="after")
    def _one(self) -> _SpeedSpec:
        if (self.constant_m_s is None) == (self.csv is None):
            raise ValueError("give exactly one of constant_m_s (0..15 m/s) or csv (time_s,speed_m_s)")
        return self


class _UndulationSpec(_Strict):
    amplitude_m: float = Field(ge=-1.0, le=1.0)
    wavelength_m: float = Field(ge=0.5, le=10_000.0)
    phase_rad: float = Field(default=0.0, ge=-10.0, le=10.0)


class _CrossWaveSpec(_Strict):
    amplitude_rad: float = Field(ge=-0.5, le=0.5)
    wavelength_m: float = Field(ge=0.5, le=10_000.0)
    phase_rad: float = Field(default=0.0, ge=-10.0, le=10.0)


class _TerrainSpec(_Strict):
    grade_rad: float = Field(default=0.0, ge=-0.5, le=0.5)
    cross_slope_rad: float = Field(default=0.0, ge=-0.5, le=0.5)
    undulation: list[_UndulationSpec] = Field(default=[], max_length=MAX_TERRAIN_WAVES)
    cross_slope_wave: list[_CrossWaveSpec] = Field(default=[], max_length=MAX_TERRAIN_WAVES)
    csv: str | None = Field(default=None, min_length=1)

    @model_validator(mode="after")
    def _csv_alone(self) -> _TerrainSpec:
        sines = self.grade_rad or self.cross_slope_rad or self.undulation or self.cross_slope_wave
        if self.csv is not None and sines:
            raise ValueError("csv replaces grade_rad, cross_slope_rad, undulation and cross_slope_wave: give one kind")
        peak = abs(self.cross_slope_rad) + sum(abs(w.amplitude_rad) for w in self.cross_slope_wave)
        if peak > 0.5:
            raise ValueError(f"cross slope peaks at {peak:g} rad: cross_slope_rad + wave amplitudes must be <= 0.5")
        # the steepest the sines can add up to, as a CSV profile's slope is bounded (0.3 m at 0.5 m wavelength,
        # a slope of 3.8, loaded and failed later as "no ground-distance reading")
        slope = abs(math.tan(self.grade_rad)) + sum(
            2 * math.pi * abs(u.amplitude_m) / u.wavelength_m for u in self.undulation
        )
        if slope > MAX_TERRAIN_SLOPE:
            raise ValueError(
                f"the ground's slope reaches {slope:.3g}: tan(grade_rad) + the sum of 2π·|amplitude_m| / wavelength_m "
                f"over terrain.undulation must be <= {MAX_TERRAIN_SLOPE:g} (45°)"
            )
        return self


class _SignalsSpec(_Strict):
    row_offset_rms_m: float = Field(default=0.0, ge=0.0, le=1.0)  # no crop row unless one is given
    row_wavelength_min_m: float = Field(default=3.0, ge=0.1, le=1000.0)
    row_wavelength_max_m: float = Field(default=30.0, ge=0.1, le=1000.0)
    row_noise_rms_m: float = Field(default=0.0, ge=0.0, le=0.5)
    row_rate_hz: float = Field(default=10.0, ge=0.1, le=100.0)
    row_camera_ahead_m: float = Field(default=0.0, ge=0.0, le=20.0)
    ground_sensor_ahead_m: float = Field(default=0.0, ge=0.0, le=20.0)
    ground_sensor_mount_height_m: float = Field(default=0.8, ge=0.1, le=3.0)
    ground_sensor_noise_rms_m: float = Field(default=0.003, ge=0.0, le=0.05)
    seed: int = Field(default=0, ge=0, le=2**63 - 1)

    @model_validator(mode="after")
    def _band(self) -> _SignalsSpec:
        if self.row_wavelength_max_m < self.row_wavelength_min_m:
            raise ValueError(
                f"row_wavelength_max_m = {self.row_wavelength_max_m} must be >= "
                f"row_wavelength_min_m = {self.row_wavelength_min_m}"
            )
        return self


class _ScenarioSpec(_Strict):
    schema_version: Literal[1]
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = Field(default="", max_length=500)
    duration_s: float = Field(gt=0.0, le=3600.0)
    tractor: _TractorSpec = Field(default_factory=_TractorSpec)
    speed: _SpeedSpec
    terrain: _TerrainSpec = Field(default_factory=_TerrainSpec)
    signals: _SignalsSpec = Field(default_factory=_SignalsSpec)


@dataclass(frozen=True)
class Scenario:
    """A validated scenario: its name, description, duration [s] and the twin it drives."""

    name: str
    description: str
    duration_s: float
    twin: TerrainTwin
    source: str


# --- CSV -------------------------------------------------------------------------------------


def _read_csv(
    where: Traversable | Path, required: tuple[str, ...], optional: tuple[str, ...] = (), *, key: str = "csv"
) -> tuple[dict[str, list[float]], list[int]]:
    """Columns of a CSV file with a header, and the file line of each data row; every error names the
    file and line (blank lines are skipped and counted; a UTF-8 byte-order mark is allowed); a missing file
    names the scenario's ``key`` that gave it."""
    name = str(where)
    if not where.is_file():
        raise ScenarioError(
            f"{key}: CSV file {name} "
            + ("is not a file" if _exists(where) else "does not exist")
            + " (a path relative to the scenario file's folder)"
        )
    text = read_text_file(where, "CSV file", ScenarioError, max_bytes=MAX_CSV_BYTES).removeprefix("\ufeff")
    rows = csv.reader(io.StringIO(text))

    def next_row() -> list[str] | None:
        # a stray quote reads the rest of the file as one cell: csv.Error, a traceback before (a fuzz trial)
        first = rows.line_num + 1
        try:
            return next(rows, None)
        except csv.Error as exc:
            raise ScenarioError(f"{name} line {first}: {csv_error_words(exc, first, rows.line_num)}") from None

    header = next_row()
    if header is None:
        raise ScenarioError(f"{name}: empty file, expected a header {','.join(required)}")
    header = [h.strip() for h in header]
    if len(header) == 1 and ";" in header[0]:  # the wording of the other CSV readers' (hitch track, calibration)
        raise ScenarioError(
            f"{name} line 1: the header is separated by semicolons (a spreadsheet's CSV with decimal commas?); "
            f"save it as CSV with commas between cells and decimal points: {','.join(required)}"
        )
    allowed = required + optional
    if (
        header[: len(required)] != list(required)
        or any(h not in allowed for h in header)
        or len(set(header)) != len(header)
    ):
        raise ScenarioError(
            f"{name} line 1: header {','.join(header)!r} must be {','.join(required)}"
            + (f" optionally followed by {','.join(optional)}" if optional else "")
        )
    out: dict[str, list[float]] = {h: [] for h in header}
    lines: list[int] = []
    while (row := next_row()) is not None:
        line = rows.line_num
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise ScenarioError(f"{name} line {line}: {len(row)} values, expected {len(header)} ({','.join(header)})")
        for h, cell in zip(header, row, strict=True):
            try:
                v = float(cell)
            except ValueError:
                raise ScenarioError(f"{name} line {line}: {h} = {cell.strip()!r} is not a number") from None
            if not math.isfinite(v):
                raise ScenarioError(f"{name} line {line}: {h} = {cell.strip()!r} must be finite")
            out[h].append(v)
        lines.append(line)
    if len(out[required[0]]) < 1:
        raise ScenarioError(f"{name}: no data rows after the header")
    return out, lines


def _exists(where: Traversable | Path) -> bool:
    return where.exists() if isinstance(where, Path) else where.is_dir()


def _csv_check(
    name: str, col: str, values: list[float], lines: list[int], lo: float, hi: float, *, increasing: bool = False
) -> None:
    for i, v in enumerate(values):
        if not lo <= v <= hi:
            raise ScenarioError(f"{name} data row {i + 1} (line {lines[i]}): {col} = {v:g} outside [{lo:g}, {hi:g}]")
        if increasing and i and not v > values[i - 1]:
            raise ScenarioError(f"{name} data row {i + 1} (line {lines[i]}): {col} = {v:g} must increase")


def _speed(spec: _SpeedSpec, base: Traversable | Path) -> SpeedProfile:
    if spec.csv is None:
        assert spec.constant_m_s is not None
        return SpeedProfile.constant(spec.constant_m_s)
    where = base / spec.csv
    cols, lines = _read_csv(where, ("time_s", "speed_m_s"), key="speed.csv")
    _csv_check(str(where), "time_s", cols["time_s"], lines, 0.0, 1e6, increasing=True)
    _csv_check(str(where), "speed_m_s", cols["speed_m_s"], lines, 0.0, 15.0)
    return SpeedProfile(tuple(cols["time_s"]), tuple(cols["speed_m_s"]))


def _ground(spec: _TerrainSpec, base: Traversable | Path) -> GroundProfile:
    if spec.csv is None:
        return SineGround(
            grade_rad=spec.grade_rad,
            cross_slope_rad_0=spec.cross_slope_rad,
            undulations=tuple(Undulation(u.amplitude_m, u.wavelength_m, u.phase_rad) for u in spec.undulation),
            cross_waves=tuple(
                CrossSlopeWave(w.amplitude_rad, w.wavelength_m, w.phase_rad) for w in spec.cross_slope_wave
            ),
        )
    where = base / spec.csv
    cols, lines = _read_csv(where, ("distance_m", "height_m"), ("cross_slope_rad",), key="terrain.csv")
    if len(cols["distance_m"]) < 2:
        raise ScenarioError(f"{where}: a terrain profile needs at least 2 data rows")
    d, h = cols["distance_m"], cols["height_m"]
    _csv_check(str(where), "distance_m", d, lines, -1e6, 1e6, increasing=True)
    _csv_check(str(where), "height_m", h, lines, -100.0, 100.0)
    for i in range(1, len(d)):
        slope = (h[i] - h[i - 1]) / (d[i] - d[i - 1])
        if abs(slope) > MAX_TERRAIN_SLOPE:
            raise ScenarioError(
                f"{where} lines {lines[i - 1]}-{lines[i]}: height_m changes by {h[i] - h[i - 1]:g} m over "
                f"{d[i] - d[i - 1]:g} m (slope {slope:.3g}; allowed at most {MAX_TERRAIN_SLOPE:g}, 45°); "
                "heights and distances are in m"
            )
    cross = cols.get("cross_slope_rad")
    if cross is not None:
        _csv_check(str(where), "cross_slope_rad", cross, lines, -0.5, 0.5)
    return SampledGround(tuple(cols["distance_m"]), tuple(cols["height_m"]), None if cross is None else tuple(cross))


# --- loading ---------------------------------------------------------------------------------


def scenario_from_dict(data: Any, *, source: str = "<dict>", base: Traversable | Path | None = None) -> Scenario:
    """Validate parsed TOML ``data``; CSV paths are relative to ``base`` (default: the working folder)."""
    try:
        spec = _ScenarioSpec.model_validate(data)
    except ValidationError as err:
        raise ScenarioError(format_validation_error("scenario", source, err, _ScenarioSpec)) from None
    root: Traversable | Path = Path(".") if base is None else base
    s, tr = spec.signals, spec.tractor
    try:
        twin = TerrainTwin(
            ground=_ground(spec.terrain, root),
            speed=_speed(spec.speed, root),
            tractor=TractorGeometry(tr.wheelbase_m, tr.track_m, tr.suspension),
            row=RowSignal(
                rms_m=s.row_offset_rms_m,
                wavelength_min_m=s.row_wavelength_min_m,
                wavelength_max_m=s.row_wavelength_max_m,
                noise_rms_m=s.row_noise_rms_m,
                rate_hz=s.row_rate_hz,
                seed=s.seed,
                camera_ahead_m=s.row_camera_ahead_m,
            ),
            implement_behind_m=tr.implement_behind_m,
            ground_sensor=LookAheadGroundSensor(
                ahead_m=s.ground_sensor_ahead_m,
                mount_height_m=s.ground_sensor_mount_height_m,
                noise_rms_m=s.ground_sensor_noise_rms_m,
                seed=s.seed,
            ),
        )
    except TerrainError as exc:
        raise ScenarioError(f"scenario {source}: {exc}") from None
    return Scenario(spec.name, spec.description, spec.duration_s, twin, source)


def _builtin_folder() -> Traversable:
    return resources.files("bridge.sim") / "scenarios"


def builtin_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``bridge/sim/scenarios/``."""
    return toml_names(_builtin_folder())


def toml_names(folder: Traversable) -> list[str]:
    """The names of the ``.toml`` files in ``folder`` (without the suffix), sorted."""
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def read_named_toml(
    name_or_path: str | Path, folder: Traversable, kind: str, error: type[HitchInputError]
) -> tuple[dict[str, Any], Traversable | Path, Traversable | Path]:
    """A ``kind`` file (``scenario``, ``field``) from a ``.toml`` path or a built-in name in ``folder``:
    ``(data, where it was read, the folder its relative paths start from)``; ``error`` names what is wrong."""
    p = Path(name_or_path)
    where: Traversable | Path
    base: Traversable | Path
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise error(f"{kind} file {p} does not exist")
        where, base = p, p.parent
    else:
        where = folder / f"{name_or_path}.toml"
        if not where.is_file():
            raise error(
                f"{kind} {str(name_or_path)!r} not found; built-in {kind}s: {', '.join(toml_names(folder))} "
                "(or give a path to a .toml file)"
            )
        base = folder
    try:
        return tomllib.loads(read_text_file(where, kind, error)), where, base
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{kind} {where} is not valid TOML: {exc}") from None


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A scenario from a ``.toml`` path or a built-in name."""
    data, where, base = read_named_toml(name_or_path, _builtin_folder(), "scenario", ScenarioError)
    return scenario_from_dict(data, source=str(where), base=base)
