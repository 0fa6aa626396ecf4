"""The count approach's choice (planner.trajectory.count_approach) against a brute force over counts, sides
and back-offs, its bounds and sides, and its errors; the profile's ``motion.count_approach`` section."""

from __future__ import annotations

import numpy as np
import pytest

from planner.profiles import ProfileError, load_profile, profile_from_dict
from planner.trajectory import CountApproachError, build_count_approach

LO, HI = np.zeros(5), np.full(5, 1000.0)


def _same(v: float, n: int = 1) -> list[list[float]]:
    return [[v] * n for _ in range(5)]


def _brute(u, below, above, lo, hi, sides):
    """The nearest stop over every count in range, side allowed and back-off (the definition)."""
    best = []
    for i in range(5):
        opts = [
            abs(c + s - u[i])
            for c in range(int(lo[i]), int(hi[i]) + 1)
            for d, offs in ((1, below[i]), (-1, above[i]))
            if sides[i] in (0, d)
            for k, s in enumerate(offs, start=1)
            if lo[i] <= c - d * k <= hi[i]
        ]
        best.append(min(opts))
    return np.array(best)


def test_the_choice_is_the_nearest_stop_over_all_counts_sides_and_back_offs(rng):
    for _ in range(150):
        u = rng.uniform(8.0, 992.0, 5)
        n = rng.integers(1, 4, 5)
        below = [sorted(rng.uniform(-0.45, 0.45, k)) for k in n]
        above = [sorted(rng.uniform(-0.45, 0.45, k), reverse=True) for k in n]
        sides = rng.integers(-1, 2, 5)
        a = build_count_approach(u, below, above, LO, HI, sides=sides)
        err = np.abs(a.residual_counts)
        assert np.allclose(err, _brute(u, below, above, LO, HI, sides), atol=1e-12)
        assert np.array_equal(a.via_counts, a.final_counts - a.directions * a.back_off_counts)
        expect = [
            (below if d > 0 else above)[i][k - 1] + c
            for i, (c, d, k) in enumerate(zip(a.final_counts, a.directions, a.back_off_counts, strict=True))
        ]
        assert np.allclose(a.stop_counts, expect)
        assert np.all((sides == 0) | (a.directions == sides))  # a fixed side is kept
        assert np.all(err <= 0.5 + 0.45 + 1e-12)


def test_offsets_half_a_count_apart_halve_the_worst_error(rng):
    """Stops at c + 0.25 (rising) and c − 0.25 (falling): one every half count, error ≤ 0.25 count; with one
    side only the same comes from two back-offs (c − 0.25, c + 0.25 from below)."""
    u = rng.uniform(10.0, 990.0, (400, 5))
    worst = max(np.max(np.abs(build_count_approach(x, _same(0.25), _same(-0.25), LO, HI).residual_counts)) for x in u)
    assert 0.24 < worst <= 0.25 + 1e-12
    one_side = [[-0.25, 0.25]] * 5
    worst1 = max(
        np.max(np.abs(build_count_approach(x, one_side, _same(0.0), LO, HI, sides=np.ones(5)).residual_counts))
        for x in u
    )
    assert 0.24 < worst1 <= 0.25 + 1e-12
    plain = max(np.max(np.abs(build_count_approach(x, _same(0.0), _same(0.0), LO, HI).residual_counts)) for x in u)
    assert plain > 0.49  # zero offsets: the nearest count, up to half a count off


def test_the_via_and_the_final_count_stay_within_the_bounds():
    u = np.array([0.2, 999.8, 500.0, 1.0, 998.9])
    a = build_count_approach(u, _same(0.3, 3), _same(-0.3, 3), LO, HI)
    assert np.all((LO <= a.via_counts) & (a.via_counts <= HI))
    assert np.all((LO <= a.final_counts) & (a.final_counts <= HI))
    assert a.directions[0] == -1 and a.directions[1] == 1  # at the ends only the inward side has room
    one_count = HI.copy()
    one_count[0] = 0.0  # the lift may take count 0 only: no via has room
    with pytest.raises(CountApproachError, match=r"lift: no count near 0\.20 with its via within \[0, 0\]"):
        build_count_approach(u, _same(0.3), _same(-0.3), LO, one_count)


def test_bad_input_names_the_field_and_the_range():
    u = np.full(5, 100.0)
    bad = _same(0.1)
    bad[1] = [1.5]
    with pytest.raises(CountApproachError, match=r"from_below_counts\.tilt: 1\.5 is outside the allowed \(-1, 1\)"):
        build_count_approach(u, bad, _same(0.0), LO, HI)
    with pytest.raises(CountApproachError, match=r"from_above_counts\.lift: need 1 to 5 offsets, got 6"):
        build_count_approach(u, _same(0.0), [[0.0] * 6] + _same(0.0)[1:], LO, HI)
    with pytest.raises(CountApproachError, match="unrounded_counts: need 5 values"):
        build_count_approach(u[:4], _same(0.0), _same(0.0), LO, HI)
    with pytest.raises(CountApproachError, match=r"unrounded_counts\.lift: nan"):
        build_count_approach([np.nan, 1, 1, 1, 1], _same(0.0), _same(0.0), LO, HI)
    with pytest.raises(CountApproachError, match="sides: each must be -1, 0 or 1"):
        build_count_approach(u, _same(0.0), _same(0.0), LO, HI, sides=[0.5, 0, 0, 0, 0])
    with pytest.raises(CountApproachError, match=r"via_hold_s: .* \(0, 10\] s"):
        build_count_approach(u, _same(0.0), _same(0.0), LO, HI, via_hold_s=0.0)
    with pytest.raises(CountApproachError, match=r"lift: no count near 2000\.00"):
        build_count_approach([2000.0, 1, 1, 1, 1], _same(0.0), _same(0.0), LO, HI)


def test_the_profile_section_loads_and_refuses_bad_values():
    data = load_profile("thesis-t132").model_dump()
    below = {"lift": [0.19, 0.31, 0.43], "tilt": [-0.08], "top": [-0.13], "left": [-0.12], "right": [-0.12]}
    above = {"lift": [-0.19], "tilt": [0.08], "top": [0.11], "left": [0.07], "right": [0.12]}
    data["motion"]["count_approach"] = {"from_below_counts": below, "from_above_counts": above}
    ca = profile_from_dict(data).motion.count_approach
    assert ca is not None and ca.from_below_counts.values()[0] == (0.19, 0.31, 0.43)
    assert (ca.keep_arrival_side, ca.via_hold_s, ca.final_hold_s) == (True, 0.6, 0.6)
    data["motion"]["count_approach"]["from_above_counts"] = {**above, "lift": [-1.2]}
    with pytest.raises(ProfileError, match=r"count_approach\.from_above_counts\.lift"):
        profile_from_dict(data)
    data["motion"]["count_approach"]["from_above_counts"] = {**above, "lift": []}
    with pytest.raises(ProfileError, match=r"count_approach\.from_above_counts\.lift"):
        profile_from_dict(data)
    assert load_profile("thesis-t132").motion.count_approach is None  # off unless a profile sets it
