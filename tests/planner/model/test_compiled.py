"""CasADi functions compiled to C: the virtual machine's values bit for bit, cached, and a clean fallback."""

from __future__ import annotations

import logging

import casadi as ca
import numpy as np
import pytest

from planner.model import compiled
from planner.model.compiled import compile_functions, compiler
from planner.model.exact_inverse import ExactInverse, _build
from planner.model.fast_function import FastFunction, MappedFunction
from planner.model.kinematics import HitchModel

needs_cc = pytest.mark.skipif(compiler() is None, reason="no C compiler on this machine")


def _tiny(name: str) -> ca.Function:
    x = ca.SX.sym("x", 3)
    return ca.Function(name, [x], [ca.vertcat(ca.sin(x[0]) * ca.sqrt(x[1]), ca.atan2(x[2], x[0]) / 3.0)])


@pytest.fixture(scope="module")
def model() -> HitchModel:
    return HitchModel.from_profile()


@needs_cc
def test_compiled_is_an_external_with_the_same_values_bit_for_bit(model):
    """The exact inverse (with rates and with its Jacobian), the forward points and features over
    poses and actuators across the workspace: compiled = virtual machine, every output, bit for
    bit (NaN where NaN)."""
    rng = np.random.default_rng(7)
    inv_rate = _build(model, rate=True)
    ws = model.workspace
    lo = np.array([ws[k][0] for k in ("x", "z", "roll", "pitch")])
    hi = np.array([ws[k][1] for k in ("x", "z", "roll", "pitch")])
    poses = lo[:, None] + (hi - lo)[:, None] * rng.random((4, 64)) * 1.2 - 0.1 * (hi - lo)[:, None]
    q = model.neutral[:, None] + rng.normal(0.0, 0.02, (5, 64))
    for fn, args in (
        (inv_rate.map(64), (poses, rng.normal(0.0, 0.1, (4, 64)))),
        (model.points_function.map(64), (q,)),
        (model.feature_function.map(64), (q,)),
        (ExactInverse(model).function.map(64), (poses,)),
    ):
        (ext,) = compile_functions([fn])
        assert ext.class_name() == "External"
        vm, cc = FastFunction(fn)(*args), FastFunction(ext)(*args)
        for a, b in zip(vm, cc, strict=True):
            assert np.array_equal(a, b, equal_nan=True)


@needs_cc
def test_mapped_compiled_equals_single_calls_and_the_inverse_batch_is_compiled(model):
    inv = ExactInverse(model)
    rng = np.random.default_rng(3)
    P = np.array([0.0, 0.6, 0.0, 0.0]) + rng.normal(0.0, 0.02, (37, 4))
    q, jac, checks, y_yaw = MappedFunction(inv.function, compiled=True)(P.T)
    for k in range(len(P)):
        qk, jk, ck, yk = (o.copy() for o in FastFunction(inv.function)(P[k]))
        assert np.array_equal(q[:, k], qk[:, 0]) and np.array_equal(jac[:, 4 * k : 4 * k + 4], jk)
        assert np.array_equal(checks[:, k], ck[:, 0]) and np.array_equal(y_yaw[:, k], yk[:, 0])
    inv.solve_batch(P, np.zeros_like(P))
    assert inv._batch is not None and all(f.function.class_name() == "External" for f in inv._batch._fast.values())


@needs_cc
def test_library_is_built_once_into_the_cache_and_loaded_again(tmp_path, monkeypatch):
    monkeypatch.setenv("HITCH_CASADI_CACHE", str(tmp_path))
    f = _tiny("hitch_test_tiny_cache")
    (ext,) = compile_functions([f])
    libs = list(tmp_path.glob("hitch_*.so"))
    assert len(libs) == 1 and not list(tmp_path.glob(".build-*"))  # no temporary left behind
    x = np.array([0.3, 2.0, -0.7])
    assert np.array_equal(np.array(ext(x)), np.array(f(x)))
    compiled._LOADED.clear()  # a new process: the library on disk is loaded, not rebuilt
    mtime = libs[0].stat().st_mtime_ns
    (ext2,) = compile_functions([f])
    assert ext2.class_name() == "External" and libs[0].stat().st_mtime_ns == mtime
    assert list(tmp_path.glob("hitch_*.so")) == libs


def test_disabled_returns_the_functions_themselves(monkeypatch):
    monkeypatch.setenv("HITCH_CASADI_COMPILE", "0")
    assert compiler() is None
    f, g = _tiny("hitch_test_tiny_off_a"), _tiny("hitch_test_tiny_off_b")
    out = compile_functions([f, g])
    assert out[0] is f and out[1] is g


def test_compiler_failure_falls_back_to_the_virtual_machine(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("HITCH_CASADI_CACHE", str(tmp_path))
    monkeypatch.setenv("CC", "false")  # a "compiler" that always fails
    f = _tiny("hitch_test_tiny_fail")
    with caplog.at_level(logging.WARNING, logger="planner.model.compiled"):
        (out,) = compile_functions([f])
    assert out is f and "compiling failed" in caplog.text
    assert not list(tmp_path.glob("hitch_*.so"))
    mf = MappedFunction(f, compiled=True)  # still evaluates, in the virtual machine
    X = np.array([[0.3, 2.0, -0.7], [0.1, 1.0, 0.2]]).T
    (res,) = mf(X)
    assert np.array_equal(res[:, 1], np.array(f(X[:, 1])).ravel())


def test_names_must_be_distinct():
    f = _tiny("hitch_test_tiny_dup")
    with pytest.raises(ValueError, match="distinct"):
        compile_functions([f, f])
