"""FastFunction and MappedFunction: the values of plain CasADi calls, over any number of columns."""

import casadi as ca
import numpy as np
import pytest

from planner.model.exact_inverse import ExactInverse
from planner.model.fast_function import FastFunction, MappedFunction
from planner.model.types import ModelInputError


@pytest.fixture(scope="module")
def inverse(model):
    return ExactInverse(model)


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 63, 64, 65, 137])
def test_mapped_columns_are_single_calls_bit_for_bit(model, inverse, rng, n):
    """Every chunk size and remainder: each column block is the plain Function call's output
    (a vector output and the 5x4 Jacobian, whose blocks sit side by side)."""
    p0 = model.neutral_pose.controlled()
    P = p0 + np.array([0.05, 0.1, 0.03, 0.03]) * (2 * rng.random((n, 4)) - 1)
    outs = MappedFunction(inverse.function)(P.T)
    assert [o.shape for o in outs] == [(5, n), (5, 4 * n), (3, n), (2, n)]
    for k in range(n):
        ref = [np.array(r) for r in inverse.function(P[k])]
        assert np.array_equal(outs[0][:, k], ref[0][:, 0])
        assert np.array_equal(outs[1][:, 4 * k : 4 * k + 4], ref[1])
        assert np.array_equal(outs[2][:, k], ref[2][:, 0]) and np.array_equal(outs[3][:, k], ref[3][:, 0])


def test_mapped_results_are_fresh_arrays(model, inverse):
    mf = MappedFunction(inverse.function)
    p = model.neutral_pose.controlled()
    a = mf(np.tile(p, (3, 1)).T)[0]
    b = mf(np.tile(p + [0.01, 0.0, 0.0, 0.0], (3, 1)).T)[0]
    assert not np.array_equal(a, b)  # the first result was not overwritten
    assert np.array_equal(a, mf(np.tile(p, (3, 1)).T)[0])


def test_mapped_function_refuses_what_it_cannot_map(inverse):
    x = ca.SX.sym("x", 2, 2)
    with pytest.raises(ModelInputError, match="column vector"):
        MappedFunction(ca.Function("m", [x], [x[0, 0]]))
    with pytest.raises(ModelInputError, match="chunks"):
        MappedFunction(inverse.function, chunks=(8, 2))
    with pytest.raises(ModelInputError, match="chunks"):
        MappedFunction(inverse.function, chunks=(1, 8))
    with pytest.raises(ModelInputError, match="expected 1 inputs"):
        MappedFunction(inverse.function)(np.zeros((4, 3)), np.zeros((4, 3)))


def test_fast_function_matches_a_plain_call(model, inverse):
    p = model.neutral_pose.controlled()
    ref = [np.array(r) for r in inverse.function(p)]
    out = FastFunction(inverse.function)(p)
    assert all(np.array_equal(o, r) for o, r in zip(out, ref, strict=True))
