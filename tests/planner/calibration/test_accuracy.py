"""The thesis's accuracy test as pure code: the pose sequence and the statistics against hand-computed values."""

import math

import numpy as np
import pytest

from planner.calibration.accuracy import (
    THESIS_ACCURACY,
    AccuracyError,
    Deflections,
    accuracy_statistics,
    thesis_sequence,
)
from planner.errors import HitchInputError


def test_the_sequence_deflects_each_dof_twice_positive_then_negative_then_combined():
    d = Deflections()
    seq = thesis_sequence(d)
    measured = [p for p in seq if p.measure]
    assert [p.label for p in measured] == [
        f"{n}{s}" for n in ("x", "z", "roll", "pitch") for s in ("+", "+", "-", "-")
    ] + ["combined+", "combined+", "combined-", "combined-"]
    # home between every two measured poses, and at the end
    assert all(not p.measure and p.offset == (0, 0, 0, 0) for p in seq[1::2]) and len(seq) == 2 * len(measured)
    sizes = d.as_array()
    for k in range(4):  # x, z, roll, pitch
        plus, minus = measured[4 * k], measured[4 * k + 2]
        expected = np.zeros(4)
        expected[k] = sizes[k]
        assert np.allclose(plus.offset, expected) and np.allclose(minus.offset, -expected)
    assert np.allclose(measured[16].offset, 0.5 * sizes * [1, 1, 1, -1])
    assert np.allclose(measured[18].offset, -np.asarray(measured[16].offset))
    # the goal is home + offset
    home = np.array([0.0, 0.11, 0.0, 0.01])
    assert measured[4].goal(home) == pytest.approx({"x": 0.0, "z": 0.21, "roll": 0.0, "pitch": 0.01})


def test_a_subset_sequence_and_bad_sizes():
    seq = thesis_sequence(dofs=("z",), combined=False)
    assert [p.label for p in seq if p.measure] == ["z+", "z+", "z-", "z-"]
    with pytest.raises(AccuracyError, match="dofs"):
        thesis_sequence(dofs=("yaw",))
    with pytest.raises(AccuracyError, match="dofs: z given twice"):  # a new user's report: z,z ran z twice
        thesis_sequence(dofs=("z", "z"))
    with pytest.raises(HitchInputError, match=r"deflections.z_m must be a number in \(0, 1\]"):
        Deflections(z_m=-0.1)
    with pytest.raises(ValueError, match="home must be 4 finite"):
        seq[0].goal([0.0, math.nan, 0.0, 0.0])


def test_statistics_match_hand_computed_values():
    commanded = np.zeros((4, 4))
    errors = np.array(
        [
            [0.001, -0.002, 0.0, 0.010],
            [0.003, -0.004, 0.0, 0.010],
            [-0.002, 0.002, 0.001, 0.010],
            [-0.004, 0.002, 0.003, 0.010],
        ]
    )
    st = accuracy_statistics(commanded, commanded + errors, ["a", "a", "b", "b"])
    x = st["x"]
    assert x.mean == pytest.approx(-0.0005)
    assert x.mean_abs == pytest.approx(0.0025)
    assert x.max_abs == pytest.approx(0.004)
    # pooled std of the two visits of "a" (0.001, 0.003) and of "b" (-0.002, -0.004): each ±0.001 about its
    # mean, 2 degrees of freedom in all: sqrt(4e-6 / 2)
    assert x.repeatability == pytest.approx(math.sqrt(4e-6 / 2))
    assert st["pitch"].mean == pytest.approx(0.010) and st["pitch"].repeatability == pytest.approx(0.0, abs=1e-15)
    assert st["z"].mean_abs == pytest.approx(0.0025) and st["z"].max_abs == pytest.approx(0.004)
    assert st["roll"].repeatability == pytest.approx(math.sqrt(2e-6 / 2))
    assert x.as_dict()["n"] == 4
    # no repeated pose: no repeatability
    assert math.isnan(accuracy_statistics(commanded[:2], errors[:2], ["a", "b"])["x"].repeatability)


def test_bad_measurements_name_the_problem():
    with pytest.raises(AccuracyError, match="equal shape"):
        accuracy_statistics(np.zeros((2, 4)), np.zeros((3, 4)), ["a", "b"])
    with pytest.raises(AccuracyError, match="labels"):
        accuracy_statistics(np.zeros((2, 4)), np.zeros((2, 4)), ["a"])
    with pytest.raises(AccuracyError, match="finite"):
        accuracy_statistics(np.zeros((1, 4)), np.full((1, 4), np.nan), ["a"])


def test_the_thesis_figures_are_the_tables_in_si():
    assert set(THESIS_ACCURACY) == {"hybrid (3-8)", "DLS (3-9)", "geometric (3-10)"}
    hybrid = THESIS_ACCURACY["hybrid (3-8)"]
    assert hybrid["x"].mean == pytest.approx(0.00381) and hybrid["pitch"].max_abs == pytest.approx(0.062)
    assert THESIS_ACCURACY["geometric (3-10)"]["z"].max_abs == pytest.approx(0.055)
    assert THESIS_ACCURACY["DLS (3-9)"]["roll"].repeatability == pytest.approx(0.0112)
