"""EndStopZone.speed_factor: the float path gives the array path's factor and binding actuator bit for bit
(inside, in and beyond the end zones, zero and tiny rates, ties), and the factor has its closed form."""

import math
import struct

import numpy as np

from planner.limits.end_stop import EndStopZone

LO = np.array([0.10, 0.20, 0.30, 0.00, 0.05])
HI = np.array([0.40, 0.50, 0.70, 0.25, 0.35])
VEL = np.array([0.05, 0.06, 0.04, 0.05, 0.05])


def test_float_path_equals_array_path():
    zone = EndStopZone(LO, HI, VEL, 0.05)
    rng = np.random.default_rng(3)
    bound = 0
    for k in range(20_000):
        # most samples in or beyond an end zone, some rates zero or below the 1e-12 cut
        q = LO + (HI - LO) * rng.choice([rng.uniform(-0.02, 0.08), rng.uniform(0.92, 1.02), rng.random()], 5)
        qd = rng.normal(0, 0.05, 5) * (rng.random(5) < 0.8)
        if k % 50 == 0:
            qd[rng.integers(5)] = 1e-13
        if k % 97 == 0:
            qd = np.zeros(5)
        if k % 89 == 0:  # a tie between two actuators: the first binds
            q[3], qd[3] = LO[3] + (q[1] - LO[1]) * (HI[3] - LO[3]) / (HI[1] - LO[1]), qd[1] * VEL[3] / VEL[1]
        f_new, i_new = zone.speed_factor(q, qd)
        f_ref, i_ref = zone._speed_factor_arrays(q, qd)
        assert struct.pack("<d", f_new) == struct.pack("<d", f_ref) and i_new == i_ref, (k, q, qd)
        bound += i_ref is not None
    assert bound > 2000


def test_closed_form_and_fallbacks():
    zone = EndStopZone(LO, HI, VEL, 0.05)
    q = LO + 0.5 * (HI - LO)
    q[2] = HI[2] - 0.25 * 0.05 * (HI[2] - LO[2])  # a quarter into actuator 2's upper end zone
    qd = np.array([0.0, 0.01, 0.08, -0.02, 0.0])
    f, i = zone.speed_factor(q, qd)
    assert i == 2 and math.isclose(f, VEL[2] * math.sqrt(0.25) / 0.08, rel_tol=1e-12)
    assert zone.speed_factor(q, np.zeros(5)) == (1.0, None)
    # a non-finite position or rate fails closed: factor 0, naming it (it read as 1.0, "no slow-down", while
    # actuator 2 bound at 0.25; a reviewer's reproduction)
    nan = qd.copy()
    nan[0] = np.nan
    assert zone.speed_factor(q, nan) == (0.0, 0)
    q_nan = q.copy()
    q_nan[3] = np.nan
    assert zone.speed_factor(q_nan, qd) == (0.0, 3)
    assert zone.speed_factor(q, np.where(np.arange(5) == 4, np.inf, qd)) == (0.0, 4)
    empty = EndStopZone(LO, HI, VEL, 0.0)  # no zone: numpy's x / 0, not a ZeroDivisionError
    with np.errstate(divide="ignore", invalid="ignore"):
        assert empty.speed_factor(q, qd) == empty._speed_factor_arrays(q, qd)
