"""The uncertain geometry (and sensor) parameters of a hitch profile, their nominal values and scales.

The parameters are the fields the tape-measure error model perturbs (the twin's truth): every
component of ``geometry.lift_arm_pivot``, ``top_link_tractor_point`` and ``limiter_tractor_point``,
the pivot placement ``lower_link_pivot_span`` and ``pivot_height`` (scale 10 mm), the member lengths
``lower_link_length``, ``lift_rod_attachment``, ``limiter_bracket_position``,
``limiter_bracket_offset``, ``fixed_lift_rod_length`` and ``lift_arm_length`` (5 mm), and — unless
``include_ad=False`` — the AD map of every actuator as an offset and a gain of the *reading*:

    q_true = si_min + ad_offset + (1 + ad_gain) · (q_read − si_min)

where ``q_read`` is the actuator position (SI) the *nominal* AD map gives for the raw counts. The
offset's scale is 3 counts of the nominal map (in m or rad), the gain's 2 %. Writing them back into
a profile moves ``counts_min`` / ``counts_max`` (integers in the schema, so rounded to whole counts;
the strokes in SI stay). A scale is the size of the error the parameter may have before
calibration: the solver works in the scaled deltas ``u = (p − nominal) / scale``.

With ``include_lag=True`` (a profile with ``motion.final_approach``) up to four more: the **lag** of the
implement behind the mechanism, ``lag.x``, ``lag.z`` (scale 1 mm), ``lag.roll``, ``lag.pitch`` (3 mrad) —
the pin play taken up on one side — in each DOF the approach moves (offset > 0). A pose measured after a
rising approach reads the mechanism's pose minus the lag, one after a falling approach plus it (the
measurement file's ``approach`` column); the fit finds it beside the geometry (from both sides: from one
it cannot), and it is written to ``motion.final_approach.lag``, where the planner aims the mechanism that
far beyond each goal on the approach's side.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from planner.errors import HitchInputError
from planner.model.sensors import AD_COUNTS_MAX, SensorScaling
from planner.model.types import ACTUATOR_NAMES
from planner.profiles.hitch import Profile, profile_from_dict

__all__ = [
    "AD_GAIN_SCALE",
    "AD_OFFSET_SCALE_COUNTS",
    "LAG_NAMES",
    "LAG_SCALE",
    "COORDINATE_SCALE_M",
    "LENGTH_SCALE_M",
    "CalibrationError",
    "Parameter",
    "ParameterSet",
]

COORDINATE_SCALE_M = 0.010
LENGTH_SCALE_M = 0.005
AD_OFFSET_SCALE_COUNTS = 3.0
AD_GAIN_SCALE = 0.02
#: scales of lag.x, lag.z [m], lag.roll, lag.pitch [rad]: the bands of 1 mm of pin play (1 mm, 2.5, 3.3 mrad)
LAG_SCALE = (0.001, 0.001, 0.003, 0.003)
#: the lag's parameter names (x, z, roll, pitch)
LAG_NAMES = ("lag.x", "lag.z", "lag.roll", "lag.pitch")

_VECTOR_FIELDS = ("lift_arm_pivot", "top_link_tractor_point", "limiter_tractor_point")
_SCALAR_COORDINATES = ("lower_link_pivot_span", "pivot_height")
_LENGTH_FIELDS = (
    "lower_link_length",
    "lift_rod_attachment",
    "limiter_bracket_position",
    "limiter_bracket_offset",
    "fixed_lift_rod_length",
    "lift_arm_length",
)


class CalibrationError(HitchInputError):
    """A calibration input (parameters, measurements, poses) that cannot be used; names field and range."""


@dataclass(frozen=True)
class Parameter:
    """One uncertain parameter: ``name`` (``geometry.lift_arm_pivot[1]``, ``ad_offset.lift``, ``ad_gain.top``),
    nominal value, scale (its pre-calibration uncertainty) and unit (``m``, ``rad`` or ``1``)."""

    name: str
    nominal: float
    scale: float
    unit: str


def _ad_offset_unit(name: str) -> str:
    return "rad" if name == "lift" else "m"


@dataclass(frozen=True)
class ParameterSet:
    """The calibration parameters of a profile (order fixed: geometry fields, then AD offsets and gains)."""

    profile: Profile
    parameters: tuple[Parameter, ...]

    @classmethod
    def from_profile(cls, profile: Profile, *, include_ad: bool = True, include_lag: bool = False) -> ParameterSet:
        if not isinstance(profile, Profile):
            raise CalibrationError(f"profile must be a Profile, got {type(profile).__name__}")
        fa = profile.motion.final_approach
        if include_lag and fa is None:
            raise CalibrationError(
                "the lag needs the profile's motion.final_approach: the planner compensates it only where a goto "
                "ends rising (add [motion.final_approach] to the profile, or measure without the approach column)"
            )
        g = profile.geometry
        ps: list[Parameter] = []
        for f in _VECTOR_FIELDS:
            for i, v in enumerate(getattr(g, f)):
                ps.append(Parameter(f"geometry.{f}[{i}]", float(v), COORDINATE_SCALE_M, "m"))
        for f in _SCALAR_COORDINATES:
            ps.append(Parameter(f"geometry.{f}", float(getattr(g, f)), COORDINATE_SCALE_M, "m"))
        for f in _LENGTH_FIELDS:
            ps.append(Parameter(f"geometry.{f}", float(getattr(g, f)), LENGTH_SCALE_M, "m"))
        if include_ad:
            res = SensorScaling(profile).resolution
            for n, r in zip(ACTUATOR_NAMES, res, strict=True):
                ps.append(Parameter(f"ad_offset.{n}", 0.0, AD_OFFSET_SCALE_COUNTS * float(r), _ad_offset_unit(n)))
            for n in ACTUATOR_NAMES:
                ps.append(Parameter(f"ad_gain.{n}", 0.0, AD_GAIN_SCALE, "1"))
        if include_lag and fa is not None:  # in the DOF with an approach (the planner compensates no other)
            lag = fa.lag.vector() if fa.lag is not None else (0.0, 0.0, 0.0, 0.0)
            for name, v, sc, d in zip(LAG_NAMES, lag, LAG_SCALE, fa.offset(), strict=True):
                if d > 0.0:
                    ps.append(Parameter(name, float(v), sc, "m" if name in ("lag.x", "lag.z") else "rad"))
        return cls(profile, tuple(ps))

    # ------------------------------------------------------------------ views
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def nominal(self) -> np.ndarray:
        return np.array([p.nominal for p in self.parameters])

    @property
    def scale(self) -> np.ndarray:
        return np.array([p.scale for p in self.parameters])

    @property
    def include_ad(self) -> bool:
        return any(p.name.startswith("ad_") for p in self.parameters)

    @property
    def lag_index(self) -> np.ndarray:
        """Indices of lag.x, lag.z, lag.roll, lag.pitch among the parameters, those there are (only the DOF with
        an approach; empty without the lag)."""
        return np.array([self.names.index(n) for n in LAG_NAMES if n in self.names], dtype=int)

    @property
    def lag_dofs(self) -> tuple[int, ...]:
        """The DOF (0 x, 1 z, 2 roll, 3 pitch) of :attr:`lag_index`, in its order."""
        return tuple(k for k, n in enumerate(LAG_NAMES) if n in self.names)

    def __len__(self) -> int:
        return len(self.parameters)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise CalibrationError(f"unknown parameter {name!r}; allowed: {', '.join(self.names)}") from None

    def vector(self, values: ArrayLike) -> np.ndarray:
        """``values`` as a checked parameter vector (finite, one per parameter)."""
        v = np.asarray(values, dtype=float).reshape(-1)
        if v.size != len(self) or not np.all(np.isfinite(v)):
            raise CalibrationError(f"parameter vector must hold {len(self)} finite numbers, got {v.size}")
        return v

    # ------------------------------------------------------------------ profile <-> parameters
    def values_of(self, other: Profile) -> np.ndarray:
        """The parameter values that describe ``other`` (same schema) relative to this set's nominal profile:
        its geometry fields, and its AD map as the offset/gain of the nominal reading (see module)."""
        g = other.geometry
        out = []
        nom = SensorScaling(self.profile)
        tru = SensorScaling(other)
        for p in self.parameters:
            kind, rest = p.name.split(".", 1)
            if kind == "geometry":
                if rest.endswith("]"):
                    f, i = rest[:-1].split("[")
                    out.append(float(getattr(g, f)[int(i)]))
                else:
                    out.append(float(getattr(g, rest)))
            elif kind == "lag":
                fa = other.motion.final_approach
                out.append(float(getattr(fa.lag, rest)) if fa is not None and fa.lag is not None else 0.0)
            else:
                k = ACTUATOR_NAMES.index(rest)
                if kind == "ad_gain":
                    out.append(float(tru.resolution[k] / nom.resolution[k] - 1.0))
                else:
                    out.append(float((nom.counts_min[k] - tru.counts_min[k]) * tru.resolution[k]))
        return np.array(out)

    def ad_count_jacobian(self, values: ArrayLike) -> np.ndarray:
        """∂ values / ∂ (counts_min, counts_max) of every actuator at ``values`` (n, 10: columns counts_min,
        counts_max of the first actuator, then of the next; zero rows for the geometry and the lag).

        The profile stores each AD map as two whole counts (:meth:`profile_dict` rounds them), so a written
        map is off the fitted one by up to half a count at each end. With span = si_max − si_min and the
        reading's resolution r = span / (counts_max − counts_min) = r_nom · (1 + gain), offset =
        (counts_min_nom − counts_min) · r:

            ∂gain/∂counts_min = r² / (span · r_nom) = −∂gain/∂counts_max
            ∂offset/∂counts_min = −r + offset · r / span,   ∂offset/∂counts_max = −offset · r / span
        """
        v = self.vector(values)
        nom = SensorScaling(self.profile)
        out = np.zeros((len(self), 2 * len(ACTUATOR_NAMES)))
        names = self.names
        for k, n in enumerate(ACTUATOR_NAMES):
            io = names.index(f"ad_offset.{n}") if f"ad_offset.{n}" in names else None
            ig = names.index(f"ad_gain.{n}") if f"ad_gain.{n}" in names else None
            if io is None and ig is None:
                continue
            gain = float(v[ig]) if ig is not None else 0.0
            offset = float(v[io]) if io is not None else 0.0
            span = float(nom.si_max[k] - nom.si_min[k])
            r = float(nom.resolution[k]) * (1.0 + gain)
            if ig is not None:
                d = r * r / (span * float(nom.resolution[k]))
                out[ig, 2 * k : 2 * k + 2] = (d, -d)
            if io is not None:
                out[io, 2 * k : 2 * k + 2] = (-r + offset * r / span, -offset * r / span)
        return out

    def profile_dict(self, values: ArrayLike, *, name: str | None = None, lag: bool = True) -> dict[str, Any]:
        """The nominal profile's data with ``values`` written in (validated; loads with ``profile_from_dict``).

        AD counts are rounded to whole counts (the schema's integers); the strokes in SI stay. ``lag=False``:
        the lag values are left out (the nominal profile's lag stays): the fit rounds its AD map with it, so a
        fitted lag the profile refuses (more than half the approach) is reported, not lost in the fit.
        """
        v = self.vector(values)
        data = self.profile.model_dump(mode="python")
        if name is not None:
            data["name"] = name
        geo = data["geometry"]
        nom = SensorScaling(self.profile)
        ad: dict[str, dict[str, float]] = {}
        for p, x in zip(self.parameters, v, strict=True):
            kind, rest = p.name.split(".", 1)
            if kind == "geometry":
                if rest.endswith("]"):
                    f, i = rest[:-1].split("[")
                    vec = list(geo[f])
                    vec[int(i)] = float(x)
                    geo[f] = vec
                else:
                    geo[rest] = float(x)
            elif kind == "lag":
                if lag:
                    fa = data["motion"]["final_approach"]  # include_lag needs it
                    fa["lag"] = {**(fa.get("lag") or {}), rest: float(x)}
            else:
                ad.setdefault(rest, {})[kind] = float(x)
        for n, d in ad.items():
            k = ACTUATOR_NAMES.index(n)
            res_t = nom.resolution[k] * (1.0 + d.get("ad_gain", 0.0))
            if not res_t > 0:
                raise CalibrationError(f"ad_gain.{n} = {d.get('ad_gain')} makes the AD map degenerate (allowed > -1)")
            cmin = nom.counts_min[k] - d.get("ad_offset", 0.0) / res_t
            cmax = cmin + (nom.si_max[k] - nom.si_min[k]) / res_t
            lo, hi = round(cmin), round(cmax)
            if not (0 <= lo < hi <= AD_COUNTS_MAX):
                raise CalibrationError(
                    f"actuators.{n}: calibrated AD map [{lo}, {hi}] leaves the 10-bit range 0…{AD_COUNTS_MAX}"
                )
            data["actuators"][n]["counts_min"], data["actuators"][n]["counts_max"] = int(lo), int(hi)
        try:
            profile_from_dict(data, source="calibrated profile")
        except HitchInputError as exc:
            # the value was fitted, not typed: the loader's "did you mean mm?" would send the engineer to the profile
            why = re.sub(r";? ?did you mean [^;)]*", "", str(exc))
            raise CalibrationError(
                f"the calibrated parameters do not make a valid profile: {why}. The fit went far from the nominal "
                "geometry: the measurements do not fit the model; check them for a wrong value, a unit slip (mm or "
                "degrees in a column of m or rad), or a sign or left/right slip (x measured to the other side, the "
                "L and R points swapped)"
            ) from None
        return data

    def describe(self, direction: ArrayLike, *, threshold: float = 0.15, limit: int = 6) -> str:
        """A combination of parameters in words: ``0.71·geometry.pivot_height − 0.70·ad_offset.left …``
        (coefficients of a unit vector in scaled units, the largest first; smaller than ``threshold`` dropped)."""
        d = np.asarray(direction, dtype=float).reshape(-1)
        order = np.argsort(-np.abs(d))
        if d[order[0]] < 0:
            d = -d
        terms = [f"{d[i]:+.2f}·{self.names[i]}" for i in order[:limit] if abs(d[i]) >= threshold]
        return " ".join(terms).lstrip("+") if terms else f"{d[order[0]]:+.2f}·{self.names[order[0]]}"

    def subset(self, names: Sequence[str]) -> ParameterSet:
        """Only the named parameters (in this set's order)."""
        keep = set(names)
        unknown = keep - set(self.names)
        if unknown:
            raise CalibrationError(f"unknown parameter(s) {sorted(unknown)}; allowed: {', '.join(self.names)}")
        return ParameterSet(self.profile, tuple(p for p in self.parameters if p.name in keep))
