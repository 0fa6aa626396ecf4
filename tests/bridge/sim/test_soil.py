"""The soil-engaging implement: ASABE D497 draft against hand-computed values, soil patches, Brixius slip."""

import math

import numpy as np
import pytest

from bridge.sim.soil import (
    CHISEL_PLOW_STRAIGHT_POINT,
    FIELD_CULTIVATOR_PRIMARY,
    MOLDBOARD_PLOW,
    D497Coefficients,
    Implement,
    SoilError,
    SoilField,
    TractionParams,
    d497_draft_n,
    gross_traction_ratio,
    mobility_number,
    motion_resistance_ratio,
    net_traction_ratio,
    tractive_capacity_n,
    wheel_slip,
)
from planner.errors import HitchInputError

KMH = 1.0 / 3.6  # 1 km/h in m/s

# --- D497 draft ----------------------------------------------------------------------------


def test_worked_example_chisel_plow_45_tools_15_cm_10_km_h():
    # Worked SI example of the D497 equation for a chisel plow (5 cm points, 45 tools, 15 cm,
    # 10 km/h, F = 0.7 as the example takes it): 0.7·(91 + 5.4·10 + 0·10²)·45·15 = 68 512.5 N.
    d = d497_draft_n(CHISEL_PLOW_STRAIGHT_POINT, speed_m_s=10 * KMH, width=45, depth_m=0.15, texture_factor=0.7)
    assert d == pytest.approx(68_512.5, rel=1e-12)


def test_chisel_plow_table_row_by_hand():
    # 9 shanks, 20 cm, 8 km/h, medium soil (F_2 = 0.85): 0.85·(91 + 5.4·8)·9·20 = 20 532.6 N
    imp = Implement(CHISEL_PLOW_STRAIGHT_POINT, width=9, texture="medium")
    assert imp.draft_n(8 * KMH, 0.20) == pytest.approx(0.85 * (91 + 43.2) * 180, rel=1e-12)
    assert imp.draft_n(8 * KMH, 0.20) == pytest.approx(20_532.6, rel=1e-9)
    # fine (F_1 = 1.0) and coarse (F_3 = 0.65)
    assert Implement(CHISEL_PLOW_STRAIGHT_POINT, 9, "fine").draft_n(8 * KMH, 0.2) == pytest.approx(24_156.0)
    assert Implement(CHISEL_PLOW_STRAIGHT_POINT, 9, "coarse").draft_n(8 * KMH, 0.2) == pytest.approx(15_701.4)


def test_field_cultivator_by_hand():
    # 20 tools, 10 cm, 10 km/h, fine: (46 + 2.8·10)·20·10 = 14 800 N
    imp = Implement(FIELD_CULTIVATOR_PRIMARY, width=20, texture="fine")
    assert imp.draft_n(10 * KMH, 0.10) == pytest.approx(14_800.0, rel=1e-12)


def test_moldboard_plow_speed_squared_by_hand():
    # 1.4 m, 20 cm, 7 km/h, medium (0.70): 0.70·(652 + 5.1·49)·1.4·20 = 17 677.32 N
    imp = Implement(MOLDBOARD_PLOW, width=1.4, texture="medium")
    assert imp.draft_n(7 * KMH, 0.20) == pytest.approx(0.70 * (652 + 5.1 * 49) * 28, rel=1e-12)


@pytest.mark.parametrize("row", [CHISEL_PLOW_STRAIGHT_POINT, FIELD_CULTIVATOR_PRIMARY, MOLDBOARD_PLOW])
def test_draft_is_linear_in_width_and_depth(row):
    base = d497_draft_n(row, speed_m_s=2.0, width=3.0, depth_m=0.12, texture_factor=0.85)
    assert d497_draft_n(row, speed_m_s=2.0, width=6.0, depth_m=0.12, texture_factor=0.85) == pytest.approx(2 * base)
    assert d497_draft_n(row, speed_m_s=2.0, width=3.0, depth_m=0.36, texture_factor=0.85) == pytest.approx(3 * base)
    assert d497_draft_n(row, speed_m_s=2.0, width=0.0, depth_m=0.12, texture_factor=0.85) == 0.0


def test_draft_is_quadratic_in_speed_per_a_b_c():
    row = D497Coefficients("test", 100.0, 6.0, 2.0, 1.0, 0.8, 0.6, "m", 0.3)
    speeds = np.array([0.0, 4.0, 8.0, 12.0, 16.0])  # km/h
    d = [d497_draft_n(row, speed_m_s=s * KMH, width=2.0, depth_m=0.1, texture_factor=1.0) for s in speeds]
    # a quadratic fit recovers A, B, C times W·T = 20
    c2, c1, c0 = np.polyfit(speeds, d, 2)
    assert (c0 / 20, c1 / 20, c2 / 20) == pytest.approx((100.0, 6.0, 2.0), rel=1e-9)


def test_no_draft_out_of_the_soil_and_resistance_scales():
    imp = Implement(CHISEL_PLOW_STRAIGHT_POINT, 9)
    assert imp.draft_n(2.0, 0.0) == 0.0
    assert imp.draft_n(2.0, -0.05) == 0.0
    assert imp.draft_n(2.0, 0.2, resistance=1.3) == pytest.approx(1.3 * imp.draft_n(2.0, 0.2))


def test_vertical_force_is_the_stated_ratio_downward():
    imp = Implement(CHISEL_PLOW_STRAIGHT_POINT, 9, vertical_ratio=0.3)
    d = imp.draft_n(2.5, 0.2)
    assert imp.vertical_force_n(d) == pytest.approx(0.3 * d)
    assert imp.vertical_force_n(0.0) == 0.0


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (
            lambda: d497_draft_n(CHISEL_PLOW_STRAIGHT_POINT, speed_m_s=-1, width=1, depth_m=0.1, texture_factor=1),
            "speed_m_s",
        ),
        (
            lambda: d497_draft_n(CHISEL_PLOW_STRAIGHT_POINT, speed_m_s=1, width=1, depth_m=2.0, texture_factor=1),
            "depth_m",
        ),
        (
            lambda: d497_draft_n(
                CHISEL_PLOW_STRAIGHT_POINT, speed_m_s=math.nan, width=1, depth_m=0.1, texture_factor=1
            ),
            "speed_m_s",
        ),
        (lambda: Implement(CHISEL_PLOW_STRAIGHT_POINT, width=0), "width"),
        (lambda: Implement(CHISEL_PLOW_STRAIGHT_POINT, width=9, texture="loam"), "texture"),  # type: ignore[arg-type]
        (lambda: Implement(CHISEL_PLOW_STRAIGHT_POINT, width=9, vertical_ratio=2), "vertical_ratio"),
        (lambda: SoilField(variation=1.5), "variation"),
        (lambda: SoilField(patch_length_m=0.1), "patch_length_m"),
        (lambda: SoilField(seed=-1), "seed"),
        (lambda: TractionParams(cone_index_pa=0.0), "cone_index_pa"),
        (lambda: TractionParams(wheels=0), "wheels"),
        (lambda: wheel_slip(TractionParams(), -5.0), "draft_n"),
    ],
)
def test_bad_inputs_name_the_field_and_range(call, field):
    with pytest.raises(SoilError, match=field) as info:
        call()
    assert isinstance(info.value, HitchInputError)
    assert isinstance(info.value, ValueError)


# --- soil patches --------------------------------------------------------------------------


def test_patches_vary_plus_minus_30_percent_as_configured():
    f = SoilField(variation=0.3, patch_length_m=10.0, length_m=10_000.0, blend_m=0.0, seed=7)
    k = np.array([f.patch_factor(i) for i in range(f.patches)])
    assert f.patches == 1000
    assert k.min() >= 0.7 and k.max() <= 1.3
    assert k.min() < 0.71 and k.max() > 1.29  # the whole band is used
    # uniform on [0.7, 1.3]: mean 1, SD 0.3/√3 = 0.173; 1000 samples -> SE of the mean 0.0055
    assert k.mean() == pytest.approx(1.0, abs=0.02)
    assert k.std() == pytest.approx(0.3 / math.sqrt(3), rel=0.08)
    # the resistance along the field is the patch's factor
    assert f.resistance(25.0) == f.patch_factor(2)


def test_patches_are_seeded_and_blend_between_patches():
    a, b = SoilField(seed=3), SoilField(seed=3)
    assert [a.resistance(s) for s in (5.0, 55.0, 555.0)] == [b.resistance(s) for s in (5.0, 55.0, 555.0)]
    assert SoilField(seed=4).patch_factor(0) != a.patch_factor(0)
    f = SoilField(patch_length_m=20.0, blend_m=2.0, seed=1)
    prev, here = f.patch_factor(0), f.patch_factor(1)
    assert f.resistance(20.0) == pytest.approx(prev)
    assert f.resistance(21.0) == pytest.approx(0.5 * (prev + here))
    assert f.resistance(22.0) == pytest.approx(here)
    # the field repeats beyond its length
    assert f.resistance(f.length_m + 5.0) == pytest.approx(f.resistance(5.0))


def test_no_variation_is_uniform_soil():
    f = SoilField(variation=0.0)
    assert {f.resistance(s) for s in np.linspace(0, 2000, 101)} == {1.0}


# --- traction / slip -----------------------------------------------------------------------


def test_brixius_equations_by_hand():
    p = TractionParams(
        cone_index_pa=1.0e6, section_width_m=0.5, diameter_m=1.5, section_height_m=0.4, deflection_m=0.08
    )
    # Bn = (1e6·0.5·1.5/10 000)·(1 + 5·0.08/0.4)/(1 + 3·0.5/1.5) = 75·2/2 = 75
    assert mobility_number(p, 10_000.0) == pytest.approx(75.0)
    bn, s = 75.0, 0.1
    gt = 0.88 * (1 - math.exp(-7.5)) * (1 - math.exp(-0.75)) + 0.04
    mr = 1 / 75 + 0.04 + 0.5 * 0.1 / math.sqrt(75)
    assert gross_traction_ratio(bn, s) == pytest.approx(gt)
    assert motion_resistance_ratio(bn, s) == pytest.approx(mr)
    assert net_traction_ratio(bn, s) == pytest.approx(gt - mr)


def test_slip_is_zero_at_zero_draft_and_rises_with_draft():
    p = TractionParams()
    assert wheel_slip(p, 0.0) == 0.0
    drafts = np.linspace(0.0, 0.95 * tractive_capacity_n(p), 12)
    slips = [wheel_slip(p, float(d)) for d in drafts]
    assert all(b > a for a, b in zip(slips, slips[1:], strict=False))
    assert 0.0 < slips[1] < 0.05 and slips[-1] < 1.0


def test_slip_solves_the_net_traction_balance():
    # the slip returned is the travel reduction of a Brixius slip s that pulls exactly the draft
    p = TractionParams(transfer_ratio=0.0, wheels=2, wheel_load_n=36_000.0)
    d = 12_000.0
    tr = wheel_slip(p, d)
    bn = mobility_number(p, 18_000.0)
    # s0: zero net traction; s = s0 + tr·(1 - s0)
    grid = np.linspace(0.0, 0.3, 300_001)
    nt = 0.88 * (1 - np.exp(-0.1 * bn)) * (1 - np.exp(-7.5 * grid)) + 0.04 - (1 / bn + 0.04 + 0.5 * grid / np.sqrt(bn))
    s0 = float(grid[np.argmin(np.abs(nt))])
    s = s0 + tr * (1 - s0)
    assert net_traction_ratio(bn, float(s)) == pytest.approx(d / 36_000.0, abs=1e-4)


def test_more_load_or_firmer_soil_means_less_slip():
    d = 15_000.0
    base = wheel_slip(TractionParams(), d)
    assert wheel_slip(TractionParams(cone_index_pa=1.8e6), d) < base
    assert wheel_slip(TractionParams(), d, vertical_force_n=5_000.0) < base


def test_draft_beyond_tractive_capacity_is_refused_with_the_limit():
    p = TractionParams()
    cap = tractive_capacity_n(p)
    # peak net traction ratio of Brixius: at most 0.88 + 0.04 - 0.04 of the (transferred) load
    assert 10_000.0 < cap < 0.88 * (p.wheel_load_n + p.transfer_ratio * cap)
    with pytest.raises(SoilError, match="tractive capacity"):
        wheel_slip(p, 1.2 * cap)
