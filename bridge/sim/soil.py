"""A soil-engaging implement in the twin: ASABE D497 draft, a field of soil patches, wheel slip.

Pure, deterministic values (no clock, no bus, no state); :mod:`bridge.sim.draft_sensor` turns the
draft into what a lower-link draft pin measures and into the ISO 11783-7 rear hitch status.

Draft (ASABE D497.7, *Agricultural Machinery Management Data*, March 2011 (R2020): the draft equation
of its implement-draft clause and Table 1, the draft parameters and expected range for tillage and
seeding implements; docs/soil.md gives the rows used and how each value was checked)::

    D = F_i · (A + B·S + C·S²) · W · T

with D the draft [N], F_i the soil-texture adjustment of the implement (i = 1 fine, 2 medium,
3 coarse), A [N], B [N·h/km], C [N·h²/km²] the machine parameters, S the field speed [km/h], W the
width in the table's units (metres, or the number of tools/rows), T the tillage depth [cm] (1 for
minor tillage tools and seeding implements). The API is SI (m/s, m); the conversion to km/h and cm
happens only in :func:`d497_draft_n`. Table 1 gives each implement an expected range ±R of the
drafts about the equation's value; the field's soil patches (:class:`SoilField`) model a variation
of this kind along the field.

The coefficients in :data:`CHISEL_PLOW_STRAIGHT_POINT`, the field cultivator rows and
:data:`MOLDBOARD_PLOW` are those of the D497 Table 1 rows "Chisel plow, 5 cm straight point",
"Field cultivator, primary tillage" and "secondary tillage", and "Moldboard plow"; docs/soil.md
states which values were checked against which source (the chisel plough's A, B, C against a
published worked example; the texture factors F_2, F_3 and the other rows are not yet checked
against the standard's text).

Vertical force. A tine working at depth is pulled *into* the soil (suction): the soil force on
the tool has a downward component. D497 gives no vertical force; the twin uses the stated
assumption ``F_v = k_v · D`` downward on the lower links with ``k_v`` (:attr:`Implement.
vertical_ratio`, default 0.3) configurable.

Wheel slip (the tractive-performance equations of ASABE D497, Brixius (1987) for bias-ply tyres)::

    Bn  = (CI·b·d / W) · (1 + 5·δ/h) / (1 + 3·b/d)           mobility number
    GT/W = 0.88·(1 - e^(-0.1·Bn))·(1 - e^(-7.5·s)) + 0.04    gross traction ratio
    MR/W = 1/Bn + 0.04 + 0.5·s/sqrt(Bn)                      motion resistance ratio
    NT/W = GT/W - MR/W                                       net traction ratio

CI cone index [Pa], b unloaded tyre section width [m], d unloaded overall tyre diameter [m], δ tyre
deflection [m], h tyre section height [m], W dynamic wheel load [N], s slip (0..1). The drive
wheels must deliver the draft: NT = D. :func:`wheel_slip` solves NT(s) = D for s by bisection
and reports it relative to the zero-pull condition on the same surface (ASAE S296 travel
reduction: with v = ωr(1 - s) and v₀ = ωr(1 - s₀) at zero net traction, the travel reduction is
``(s - s₀)/(1 - s₀)``), so the slip is 0 at zero draft and rises with the draft. A draft beyond
the tyres' maximum net traction is refused (the tractor stalls: no steady slip exists).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from planner.errors import HitchInputError

__all__ = [
    "CHISEL_PLOW_STRAIGHT_POINT",
    "FIELD_CULTIVATOR_PRIMARY",
    "FIELD_CULTIVATOR_SECONDARY",
    "MOLDBOARD_PLOW",
    "D497Coefficients",
    "Implement",
    "SoilError",
    "SoilField",
    "Texture",
    "TractionParams",
    "d497_draft_n",
    "gross_traction_ratio",
    "mobility_number",
    "motion_resistance_ratio",
    "net_traction_ratio",
    "tractive_capacity_n",
    "wheel_slip",
]

Texture = Literal["fine", "medium", "coarse"]
_TEXTURES: tuple[Texture, ...] = ("fine", "medium", "coarse")

_M_S_TO_KM_H = 3.6
_M_TO_CM = 100.0


class SoilError(HitchInputError):
    """A soil, implement, field or traction value out of its range (named in the message)."""


def _number(name: str, value: object, lo: float, hi: float, *, open_lo: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SoilError(f"{name} must be a number, got {value!r}")
    v = float(value)
    bad_lo = v <= lo if open_lo else v < lo
    if not math.isfinite(v) or bad_lo or v > hi:
        raise SoilError(f"{name} = {value!r} is outside the allowed range {'(' if open_lo else '['}{lo:g}, {hi:g}]")
    return v


# --- ASABE D497 draft -------------------------------------------------------------------------


@dataclass(frozen=True)
class D497Coefficients:
    """One row of ASABE D497.7 Table 1.

    Attributes:
        name: the row as the table names it.
        a_n, b_n_h_per_km, c_n_h2_per_km2: the machine parameters A, B, C (D497 units: speed in km/h).
        f_fine, f_medium, f_coarse: the soil-texture adjustments F_1, F_2, F_3.
        width_units: ``"m"`` (W in metres) or ``"tools"`` (W the number of tools).
        range_fraction: the expected range ±R as a fraction (0.5 = ±50 %).
        depth_applies: True for tillage tools (T = depth in cm), False for minor tools (T = 1).
    """

    name: str
    a_n: float
    b_n_h_per_km: float
    c_n_h2_per_km2: float
    f_fine: float
    f_medium: float
    f_coarse: float
    width_units: Literal["m", "tools"]
    range_fraction: float
    depth_applies: bool = True

    def __post_init__(self) -> None:
        _number("a_n", self.a_n, 0.0, 1.0e5)
        _number("b_n_h_per_km", self.b_n_h_per_km, 0.0, 1.0e4)
        _number("c_n_h2_per_km2", self.c_n_h2_per_km2, 0.0, 1.0e3)
        for n in ("f_fine", "f_medium", "f_coarse"):
            _number(n, getattr(self, n), 0.0, 1.5, open_lo=True)
        _number("range_fraction", self.range_fraction, 0.0, 1.0)
        if self.width_units not in ("m", "tools"):
            raise SoilError(f"width_units = {self.width_units!r} must be 'm' or 'tools'")

    def texture_factor(self, texture: Texture) -> float:
        """F_i for ``texture`` ("fine", "medium", "coarse")."""
        if texture not in _TEXTURES:
            raise SoilError(f"texture = {texture!r} must be one of {', '.join(_TEXTURES)}")
        return {"fine": self.f_fine, "medium": self.f_medium, "coarse": self.f_coarse}[texture]


CHISEL_PLOW_STRAIGHT_POINT = D497Coefficients(
    name="Chisel plow, 5 cm straight point",
    a_n=91.0,
    b_n_h_per_km=5.4,
    c_n_h2_per_km2=0.0,
    f_fine=1.0,
    f_medium=0.85,
    f_coarse=0.65,
    width_units="tools",
    range_fraction=0.50,
)
"""ASABE D497.7 Table 1, major tillage tools, "Chisel plow, 5 cm straight point" (N per tool, T in cm)."""

MOLDBOARD_PLOW = D497Coefficients(
    name="Moldboard plow",
    a_n=652.0,
    b_n_h_per_km=0.0,
    c_n_h2_per_km2=5.1,
    f_fine=1.0,
    f_medium=0.70,
    f_coarse=0.45,
    width_units="m",
    range_fraction=0.40,
)
"""ASABE D497.7 Table 1, "Moldboard plow" (N per metre of width, T in cm): the row with a speed-squared term."""

FIELD_CULTIVATOR_PRIMARY = D497Coefficients(
    name="Field cultivator, primary tillage",
    a_n=46.0,
    b_n_h_per_km=2.8,
    c_n_h2_per_km2=0.0,
    f_fine=1.0,
    f_medium=0.85,
    f_coarse=0.65,
    width_units="tools",
    range_fraction=0.30,
)
"""ASABE D497.7 Table 1, "Field cultivator, primary tillage" (N per tool, T in cm)."""

FIELD_CULTIVATOR_SECONDARY = D497Coefficients(
    name="Field cultivator, secondary tillage",
    a_n=32.0,
    b_n_h_per_km=1.9,
    c_n_h2_per_km2=0.0,
    f_fine=1.0,
    f_medium=0.85,
    f_coarse=0.65,
    width_units="tools",
    range_fraction=0.25,
)
"""ASABE D497.7 Table 1, "Field cultivator, secondary tillage" (N per tool, T in cm)."""


def d497_draft_n(
    coefficients: D497Coefficients,
    *,
    speed_m_s: float,
    width: float,
    depth_m: float,
    texture_factor: float,
) -> float:
    """The ASABE D497.7 draft equation ``D = F_i·(A + B·S + C·S²)·W·T`` [N].

    Args:
        coefficients: the Table 1 row.
        speed_m_s: field speed [m/s] (0..15); S = 3.6·speed in km/h.
        width: W in the row's units (metres or number of tools), 0..100.
        depth_m: tillage depth [m] (0..1); T = 100·depth in cm (ignored for minor tools).
        texture_factor: F_i (0..1.5), e.g. :meth:`D497Coefficients.texture_factor`.
    """
    v = _number("speed_m_s", speed_m_s, 0.0, 15.0)
    w = _number("width", width, 0.0, 100.0)
    depth = _number("depth_m", depth_m, 0.0, 1.0)
    f = _number("texture_factor", texture_factor, 0.0, 1.5)
    s_km_h = v * _M_S_TO_KM_H
    t = depth * _M_TO_CM if coefficients.depth_applies else 1.0
    return f * (coefficients.a_n + coefficients.b_n_h_per_km * s_km_h + coefficients.c_n_h2_per_km2 * s_km_h**2) * w * t


@dataclass(frozen=True)
class Implement:
    """A soil-engaging implement on the lower links.

    Attributes:
        coefficients: its D497 Table 1 row.
        width: W in the row's units (metres or number of tools), (0, 100].
        texture: the field's soil texture.
        vertical_ratio: ``F_v / D`` (0..1), the downward (suction) force on the lower links per unit
            draft — an assumption of the twin, not a D497 value (docs/soil.md).
    """

    coefficients: D497Coefficients
    width: float
    texture: Texture = "medium"
    vertical_ratio: float = 0.3

    def __post_init__(self) -> None:
        _number("width", self.width, 0.0, 100.0, open_lo=True)
        self.coefficients.texture_factor(self.texture)
        _number("vertical_ratio", self.vertical_ratio, 0.0, 1.0)

    def draft_n(self, speed_m_s: float, depth_m: float, resistance: float = 1.0) -> float:
        """Draft [N] at ``speed_m_s`` and working depth ``depth_m`` (≤ 0: out of the soil, no draft),
        scaled by the local soil ``resistance`` factor (0..3) of a :class:`SoilField`."""
        r = _number("resistance", resistance, 0.0, 3.0)
        d = _number("depth_m", depth_m, -10.0, 1.0)
        if d <= 0.0:
            return 0.0
        f = self.coefficients.texture_factor(self.texture)
        return r * d497_draft_n(self.coefficients, speed_m_s=speed_m_s, width=self.width, depth_m=d, texture_factor=f)

    def vertical_force_n(self, draft_n: float) -> float:
        """The vertical soil force on the lower links [N], + downward (suction): ``vertical_ratio · D``."""
        return self.vertical_ratio * _number("draft_n", draft_n, 0.0, 1.0e7)


# --- the field: soil patches ------------------------------------------------------------------


@dataclass(frozen=True)
class SoilField:
    """Soil resistance along the field: patches of seeded random resistance.

    The field from ``s = 0`` is cut into patches of ``patch_length_m``; patch k has the resistance
    factor ``1 + variation·u_k`` with u_k uniform in [-1, 1] (seeded), so factors lie in
    ``[1 - variation, 1 + variation]`` (±30 % by default) with mean 1 and SD ``variation/√3``.
    Between patches the factor ramps linearly over ``blend_m`` (0 = steps). Distances beyond the
    field's ``length_m`` repeat the field (a long drive never runs out of soil).

    Attributes:
        variation: the patch amplitude (0..0.9).
        patch_length_m: patch length (0.5..1000 m).
        length_m: field length (patch_length_m..100 km).
        blend_m: transition length between patches (0..patch_length_m).
        seed: the random seed.
    """

    variation: float = 0.3
    patch_length_m: float = 20.0
    length_m: float = 1000.0
    blend_m: float = 2.0
    seed: int = 0
    _factors: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        _number("variation", self.variation, 0.0, 0.9)
        p = _number("patch_length_m", self.patch_length_m, 0.5, 1000.0)
        _number("length_m", self.length_m, p, 100_000.0)
        _number("blend_m", self.blend_m, 0.0, p)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**32:
            raise SoilError(f"seed = {self.seed!r} must be an integer in [0, 2^32)")
        n = math.ceil(self.length_m / p)
        u = np.random.default_rng(self.seed).uniform(-1.0, 1.0, n)
        object.__setattr__(self, "_factors", 1.0 + self.variation * u)

    @property
    def patches(self) -> int:
        """The number of patches in one field length."""
        return int(self._factors.size)

    def patch_factor(self, k: int) -> float:
        """The resistance factor of patch ``k`` (wrapping around the field)."""
        return float(self._factors[k % self._factors.size])

    def resistance(self, s: float) -> float:
        """The soil resistance factor at distance ``s`` [m] along the field."""
        x = _number("s", s, -1.0e7, 1.0e7) % (self.patches * self.patch_length_m)
        k = int(x // self.patch_length_m)
        here = self.patch_factor(k)
        into = x - k * self.patch_length_m
        if self.blend_m <= 0.0 or into >= self.blend_m:
            return here
        prev = self.patch_factor(k - 1)
        return prev + (here - prev) * into / self.blend_m


# --- traction: ASABE D497 / Brixius ---------------------------------------------------------


@dataclass(frozen=True)
class TractionParams:
    """The driven tyres and the soil under them (Brixius 1987, as ASABE D497 uses them).

    Attributes:
        cone_index_pa: soil cone index CI (50 kPa .. 5 MPa; agricultural soils are typically
            0.5..2 MPa, the default 1.2 MPa is an assumed tilled soil).
        section_width_m: unloaded tyre section width b (0.1..1.5 m).
        diameter_m: unloaded overall tyre diameter d (0.3..3 m).
        section_height_m: tyre section height h (0.05..1 m).
        deflection_m: tyre deflection δ (0..h).
        wheel_load_n: static load on all driven wheels together [N] (> 0).
        wheels: number of driven wheels sharing the load (1..8).
        transfer_ratio: extra driven-wheel load per newton of draft (0..1): weight transfer
            ``D·h_draft/L`` onto the rear axle, as a ratio h_draft/L.
    """

    cone_index_pa: float = 1.2e6
    section_width_m: float = 0.65
    diameter_m: float = 1.85
    section_height_m: float = 0.42
    deflection_m: float = 0.07
    wheel_load_n: float = 6000.0 * 0.6 * 9.80665
    wheels: int = 2
    transfer_ratio: float = 0.2

    def __post_init__(self) -> None:
        _number("cone_index_pa", self.cone_index_pa, 5.0e4, 5.0e6)
        _number("section_width_m", self.section_width_m, 0.1, 1.5)
        _number("diameter_m", self.diameter_m, 0.3, 3.0)
        h = _number("section_height_m", self.section_height_m, 0.05, 1.0)
        _number("deflection_m", self.deflection_m, 0.0, h)
        _number("wheel_load_n", self.wheel_load_n, 0.0, 1.0e6, open_lo=True)
        if isinstance(self.wheels, bool) or not isinstance(self.wheels, int) or not 1 <= self.wheels <= 8:
            raise SoilError(f"wheels = {self.wheels!r} must be an integer in [1, 8]")
        _number("transfer_ratio", self.transfer_ratio, 0.0, 1.0)


def mobility_number(p: TractionParams, wheel_load_n: float) -> float:
    """Brixius mobility number ``Bn = (CI·b·d/W)·(1 + 5δ/h)/(1 + 3b/d)`` for one wheel of load W [N]."""
    w = _number("wheel_load_n", wheel_load_n, 0.0, 1.0e6, open_lo=True)
    b, d = p.section_width_m, p.diameter_m
    return (p.cone_index_pa * b * d / w) * (1.0 + 5.0 * p.deflection_m / p.section_height_m) / (1.0 + 3.0 * b / d)


def gross_traction_ratio(bn: float, slip: float) -> float:
    """Brixius ``GT/W = 0.88·(1 - e^(-0.1·Bn))·(1 - e^(-7.5·s)) + 0.04``."""
    return 0.88 * (1.0 - math.exp(-0.1 * bn)) * (1.0 - math.exp(-7.5 * slip)) + 0.04


def motion_resistance_ratio(bn: float, slip: float) -> float:
    """Brixius ``MR/W = 1/Bn + 0.04 + 0.5·s/sqrt(Bn)``."""
    return 1.0 / bn + 0.04 + 0.5 * slip / math.sqrt(bn)


def net_traction_ratio(bn: float, slip: float) -> float:
    """Brixius ``NT/W = GT/W - MR/W``."""
    return gross_traction_ratio(bn, slip) - motion_resistance_ratio(bn, slip)


def _peak_slip(bn: float) -> float:
    # d(NT/W)/ds = 0.88·(1 - e^(-0.1 Bn))·7.5·e^(-7.5 s) - 0.5/sqrt(Bn) = 0
    k = 0.88 * (1.0 - math.exp(-0.1 * bn)) * 7.5 * math.sqrt(bn) / 0.5
    return min(1.0, max(0.0, math.log(k) / 7.5)) if k > 1.0 else 0.0


def _solve_slip(bn: float, ratio: float, hi: float) -> float:
    lo = 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if net_traction_ratio(bn, mid) < ratio:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def wheel_slip(p: TractionParams, draft_n: float, vertical_force_n: float = 0.0) -> float:
    """Travel reduction (0..1) of the driven wheels pulling ``draft_n`` [N], relative to zero pull.

    The dynamic driven-wheel load is ``wheel_load_n + transfer_ratio·D + F_v`` (the implement's
    downward force ``vertical_force_n`` [N] carried by the rear axle), shared by ``wheels``;
    NT(s) = D is solved for the Brixius slip s, and s₀ (NT = 0) is removed as ASAE S296 travel
    reduction ``(s - s₀)/(1 - s₀)``. 0 at zero draft.

    Raises:
        SoilError: a bad input, or a draft beyond the tyres' maximum net traction (named, with the limit).
    """
    d = _number("draft_n", draft_n, 0.0, 1.0e6)
    fv = _number("vertical_force_n", vertical_force_n, -1.0e6, 1.0e6)
    load = p.wheel_load_n + p.transfer_ratio * d + fv
    if load <= 0.0:
        raise SoilError(f"driven-wheel load {load:g} N must be > 0 (wheel_load_n + transfer + vertical_force_n)")
    w = load / p.wheels
    bn = mobility_number(p, w)
    s_peak = _peak_slip(bn)
    if s_peak <= 0.0 or net_traction_ratio(bn, s_peak) <= 0.0:
        raise SoilError(f"the tyres cannot move on this soil (mobility number Bn = {bn:.3g}); raise cone_index_pa")
    s0 = _solve_slip(bn, 0.0, s_peak)
    if d == 0.0:
        return 0.0
    ratio = d / load
    nt_max = net_traction_ratio(bn, s_peak)
    if ratio > nt_max:
        raise SoilError(
            f"draft_n = {d:g} N exceeds the tractive capacity {nt_max * load:.0f} N (net traction ratio "
            f"{nt_max:.3f} at slip {s_peak:.2f}, Bn = {bn:.3g})"
        )
    s = _solve_slip(bn, ratio, s_peak)
    return max(0.0, (s - s0) / (1.0 - s0))


def tractive_capacity_n(p: TractionParams) -> float:
    """The largest draft [N] the driven wheels can pull: the peak of the Brixius net traction (weight
    transfer included). On tilled soil the peak lies at a slip of 50-60 %, far beyond the 10-15 %
    a tractor works at; a controller must keep well below it."""
    lo, hi = 0.0, 1.0e6
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        try:
            wheel_slip(p, mid)
            lo = mid
        except SoilError:
            hi = mid
    return lo
