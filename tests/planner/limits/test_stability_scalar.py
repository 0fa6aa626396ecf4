"""evaluate_stability_scalar gives evaluate_stability's report bit for bit (every field, signs of zeros
included) over random poses, slopes, implements and ballasts, with the CoM inside and outside the
support triangle, and raises the same errors."""

import dataclasses
import math
import struct

import numpy as np
import pytest

from planner.limits.stability import StabilityThresholds, evaluate_stability
from planner.limits.stability_scalar import evaluate_stability_scalar
from planner.limits.tractor import ImplementRecord, StabilityInputError, load_tractor_profile


def _bits(v):
    """A value reduced to comparable bits: floats by their IEEE representation (NaN and ±0 apart)."""
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return (type(v).__name__, tuple((f.name, _bits(getattr(v, f.name))) for f in dataclasses.fields(v)))
    if isinstance(v, np.ndarray):
        return (v.dtype.str, v.shape, v.tobytes(), v.flags.writeable)
    if isinstance(v, (float, np.floating)):
        return ("f", struct.pack("<d", float(v)))
    if isinstance(v, (tuple, list)):
        return tuple(_bits(x) for x in v)
    return (type(v).__name__, v)


def _rotation(rng):
    w, x, y, z = rng.normal(size=4) / 1.0
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@pytest.fixture(scope="module")
def tractor():
    return load_tractor_profile().tractor(0.5)


def test_reports_equal_bit_for_bit(tractor):
    rng = np.random.default_rng(15)
    harrow = load_tractor_profile().implement("cat2-power-harrow-1500")
    thresholds = (StabilityThresholds(), StabilityThresholds(ssm_hard=0.3, ssm_caution=0.6, esm_caution=20_000.0))
    outside = inside = 0
    for k in range(3000):
        if k % 10 == 0:
            implement = None
        elif k % 3 == 0:
            implement = harrow
        else:  # light to very heavy, CoM far back or high: the CoM leaves the triangle sometimes
            com = (float(rng.uniform(-1, 1)), float(rng.uniform(-0.5, 4.0)), float(rng.uniform(-0.5, 3.0)))
            implement = ImplementRecord("random", "2", float(rng.uniform(10, 20_000)), com)
        T = rng.uniform([-0.5, 0.5, -0.5], [0.5, 2.5, 1.5])
        R = _rotation(rng) if k % 2 else np.eye(3)
        roll, pitch = rng.uniform(-0.9, 0.9, 2) if k % 4 else (0.0, -0.0 if k % 8 else 0.0)
        ballast = float(rng.choice([0.0, rng.uniform(0, 3000)]))
        th = thresholds[k % 2]
        ref = evaluate_stability(tractor, implement, T, R, roll, pitch, thresholds=th, front_ballast=ballast)
        new = evaluate_stability_scalar(tractor, implement, T, R, roll, pitch, thresholds=th, front_ballast=ballast)
        assert _bits(new) == _bits(ref), (k, ref, new)
        outside += ref.ssm < 0
        inside += ref.ssm > 0
    assert outside > 50 and inside > 50  # both branches of the support margin were compared


@pytest.mark.parametrize(
    "kwargs",
    [
        {"R": np.diag([1.0, 1.0, -1.0])},  # improper
        {"R": np.eye(3) * 1.01},  # not orthonormal
        {"T": [0.0, np.nan, 0.0]},
        {"slope_roll": math.pi / 2},
        {"front_ballast": -1.0},
    ],
)
def test_same_errors(tractor, kwargs):
    harrow = load_tractor_profile().implement("cat2-power-harrow-1500")
    args = {"T": [0.0, 1.0, 0.3], "R": np.eye(3), "slope_roll": 0.1, "slope_pitch": 0.0, "front_ballast": 0.0}
    args.update(kwargs)
    messages = []
    for fn in (evaluate_stability, evaluate_stability_scalar):
        with pytest.raises(StabilityInputError) as err:
            fn(
                tractor,
                harrow,
                args["T"],
                args["R"],
                args["slope_roll"],
                args["slope_pitch"],
                front_ballast=args["front_ballast"],
            )
        messages.append(str(err.value))
    assert messages[0] == messages[1]


def test_guard_stability_at_equals_the_reference_frame():
    """Guard.stability_at (the frame x_i, y_i, z_i and the stability in floats) against the numpy frame and
    evaluate_stability, bit for bit, at random reachable actuators, two slopes, with and without implement."""
    from planner.limits.guard import Guard
    from planner.limits.stability import _cross3, _dot
    from planner.model.kinematics import HitchModel
    from planner.trajectory import TrajectoryPlanner

    tp = TrajectoryPlanner(HitchModel.from_profile())
    rng = np.random.default_rng(7)
    harrow = load_tractor_profile().implement("cat2-power-harrow-1500")
    compared = 0
    for implement, slope in ((harrow, (0.1, 0.0)), (harrow, (-0.3, 0.25)), (None, (0.2, -0.1))):
        guard = Guard(tp, implement=implement)
        guard.set_slope(*slope)
        for _ in range(150):
            q = tp.inverse(*(tp.lo + rng.random(4) * (tp.hi - tp.lo)))
            P = tp.model.forward(q).points
            # the norm as sqrt of the left-to-right sum (np.linalg.norm calls BLAS, which fuses multiply-add
            # on AVX-512 machines: other last bits there)
            xi = P["L"] - P["R"]
            xi /= math.sqrt(_dot(xi, xi))
            zi = P["U"] - P["T"]
            zi /= math.sqrt(_dot(zi, zi))
            R = np.column_stack([xi, _cross3(zi, xi), zi])
            ref = evaluate_stability(
                guard.tractor,
                implement,
                P["T"],
                R,
                *slope,
                thresholds=guard.thresholds,
                front_ballast=guard.settings.front_ballast,
            )
            assert _bits(guard.stability_at(q)) == _bits(ref)
            assert _bits(guard.stability_at(q, P)) == _bits(ref)
            compared += 1
    assert compared == 450


def test_model_points_equal_forward_points():
    """HitchModel.points(q) is forward(q).points bit for bit, and refuses what forward refuses."""
    from planner.model.kinematics import HitchModel, KinematicsError
    from planner.trajectory import TrajectoryPlanner

    tp = TrajectoryPlanner(HitchModel.from_profile())
    rng = np.random.default_rng(11)
    for _ in range(50):
        q = tp.inverse(*(tp.lo + rng.random(4) * (tp.hi - tp.lo)))
        a, b = tp.model.points(q), tp.model.forward(q).points
        assert a.keys() == b.keys() and all(a[n].tobytes() == b[n].tobytes() for n in a)
    q_bad = tp.model.upper * 3.0
    errors = []
    for fn in (tp.model.points, tp.model.forward):
        with pytest.raises(KinematicsError) as err:
            fn(q_bad)
        errors.append(str(err.value))
    assert errors[0] == errors[1]
