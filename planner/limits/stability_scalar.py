"""Stability of one pose in Python floats: :func:`~planner.limits.stability.evaluate_stability` bit for bit.

:func:`evaluate_stability_scalar` takes the same arguments and returns the same
:class:`~planner.limits.stability.StabilityReport`, value for value and bit for bit, at a
fraction of the cost (the guard's jog check and the state message evaluate one pose per
control cycle; ~40 numpy calls on 3-vectors cost more than the arithmetic). It performs the
same IEEE operations in the same order on Python floats:

- a dot product of short vectors is ``a0 b0 + a1 b1 + a2 b2`` summed left to right and a norm is ``sqrt`` of
  that sum: the reference's ``stability._dot`` (not numpy's ``@`` or ``np.linalg.norm``, whose BLAS kernels fuse
  multiply and add on AVX-512 CPUs, so their last bits differ from machine to machine);
- the one matrix-vector product whose rounding is BLAS's (the implement's CoM ``R_i c_i``,
  thesis 2.41's p_i = T + R_i c_i) is left to numpy, as are the rare branches (the CoM outside
  the support triangle), which call the reference functions themselves.

The inputs are checked as the reference checks them (same errors, same messages). The
reference stays the definition: ``tests/planner/limits/test_stability_scalar.py`` compares
every field of the two reports over random poses, slopes, implements and ballasts.
"""

from __future__ import annotations

import math
import weakref

import numpy as np

from planner.limits.stability import (
    _EDGES,
    AxleLoads,
    EnergyMargins,
    LoadCase,
    StabilityReport,
    StabilityThresholds,
    SupportMargins,
    _energy_constants,
    _report,
    _segment_distance,
    _support_constants,
    _travel_margins,
    gravity_direction,
)
from planner.limits.tractor import (
    STANDARD_GRAVITY,
    ImplementRecord,
    StabilityInputError,
    Tractor,
    _rotation,
    _scalar,
    _vector3,
)

__all__ = ["evaluate_stability_scalar"]

#: per tractor: the support frame's constants as floats (V0, n, e1, e2, per edge (va, m, m . travel))
_SUPPORT_FLOATS: weakref.WeakKeyDictionary[Tractor, tuple] = weakref.WeakKeyDictionary()
#: per tractor and slope: gravity (array, floats) and the energy edges as floats
_SLOPE_FLOATS: weakref.WeakKeyDictionary[Tractor, dict[tuple[float, ...], tuple]] = weakref.WeakKeyDictionary()


def _support_floats(tractor: Tractor) -> tuple:
    const = _SUPPORT_FLOATS.get(tractor)
    if const is None:
        V, n, e1, e2, _V2, edges = _support_constants(tractor)
        const = _SUPPORT_FLOATS[tractor] = (
            V[0].tolist(),
            n.tolist(),
            e1.tolist(),
            e2.tolist(),
            tuple((va.tolist(), m.tolist(), mv) for va, m, mv in edges),
        )
    return const


def _slope_floats(tractor: Tractor, slope_roll: float, slope_pitch: float) -> tuple:
    """(g array, g floats, up floats, energy edges as floats (A, axis, lift, side)) for one slope."""
    per_slope = _SLOPE_FLOATS.setdefault(tractor, {})
    key = (slope_roll, slope_pitch, math.copysign(1.0, slope_roll), math.copysign(1.0, slope_pitch))  # ±0 apart
    const = per_slope.get(key)
    if const is None:
        g = gravity_direction(slope_roll, slope_pitch)
        up = -g
        edges = tuple(
            (A.tolist(), axis.tolist(), lift, side.tolist()) for A, axis, lift, side in _energy_constants(tractor, up)
        )
        if len(per_slope) >= 32:  # slopes change: keep the last few
            per_slope.clear()
        const = per_slope[key] = (g, g.tolist(), up.tolist(), edges)
    return const


_EYE = np.eye(3)
_DEFAULT_THRESHOLDS = StabilityThresholds()


def _vector3_checked(value) -> np.ndarray:
    """``tractor._vector3("T", value)``: the same array and errors; a finite float (3,) array checked in floats."""
    if isinstance(value, np.ndarray) and value.shape == (3,) and value.dtype == np.float64:
        a, b, c = value.tolist()
        if math.isfinite(a) and math.isfinite(b) and math.isfinite(c):
            v = value.copy()
            v.setflags(write=False)
            return v
    return _vector3("T", value)


def _rotation_checked(value) -> np.ndarray:
    """``tractor._rotation("R_i", value)``: the same array and errors, the determinant's sign in closed form.

    Only reached once R passed the orthonormality check (max |RᵀR − I| ≤ 1e-6, the reference's
    own expression): then det(R)² = det(RᵀR) lies within ~1e-5 of 1, so the rounding of either
    determinant (~1e-15) cannot change its sign and ``det < 0`` decides as LAPACK's does.
    """
    if not (isinstance(value, np.ndarray) and value.shape == (3, 3) and value.dtype == np.float64):
        return _rotation("R_i", value)
    R = np.array(value, dtype=float)
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    if not all(map(math.isfinite, (a, b, c, d, e, f, g, h, i))):
        return _rotation("R_i", value)  # its error
    if np.max(np.abs(R.T @ R - _EYE)) > 1e-6 or a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) < 0:
        return _rotation("R_i", value)  # its error
    return R


def _dot3(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def evaluate_stability_scalar(
    tractor: Tractor,
    implement: ImplementRecord | None,
    T,
    R_i,
    slope_roll: float,
    slope_pitch: float,
    *,
    thresholds: StabilityThresholds = _DEFAULT_THRESHOLDS,
    front_ballast: float = 0.0,
) -> StabilityReport:
    """:func:`~planner.limits.stability.evaluate_stability` (same arguments: ``T`` (3,) [m],
    ``R_i`` 3x3, slopes [rad], ``front_ballast`` [kg]), the same report bit for bit, faster."""
    if not isinstance(thresholds, StabilityThresholds):
        raise StabilityInputError("thresholds must be a StabilityThresholds")
    r = _scalar("slope_roll", slope_roll)
    p = _scalar("slope_pitch", slope_pitch)
    for name, v in (("slope_roll", r), ("slope_pitch", p)):
        if abs(v) >= math.pi / 2:
            raise StabilityInputError(f"{name} = {v} rad is outside the allowed range (-π/2, π/2)")
    g_arr, g, up, energy_edges = _slope_floats(tractor, r, p)

    # build_load_case (thesis 2.41: p_i = T + R_i c_i; combined CoM = Σ m p / Σ m)
    ballast = _scalar("front_ballast", front_ballast, 0.0, 20_000.0)
    M = tractor.mass
    m = M + ballast
    c_t, f_b = tractor.centre_of_mass.tolist(), tractor.front_ballast_point.tolist()
    moment = [M * c_t[k] + ballast * f_b[k] for k in range(3)]
    p_i = t = None
    m_i = 0.0
    if implement is not None:
        t = _vector3_checked(T)
        p_i = t + _rotation_checked(R_i) @ np.asarray(implement.centre_of_mass)
        p_i.setflags(write=False)
        m_i = implement.mass
        m += m_i
        pl = p_i.tolist()
        moment = [moment[k] + m_i * pl[k] for k in range(3)]
    com_l = [moment[k] / m for k in range(3)]
    com = np.array(com_l)
    com.setflags(write=False)
    load = LoadCase(m, com, m_i, p_i, t, ballast)

    # axle loads: moment balance about the rear-contact line
    mg = m * STANDARD_GRAVITY
    W1, W2 = mg * g[1], mg * g[2]
    front = ((com_l[1] - float(tractor.rear_axle[1])) * W2 - (com_l[2] - tractor.ground_z) * W1) / tractor.wheelbase
    loads = AxleLoads(float(front), float(-W2 - front))

    margins = _support(tractor, com_l, g, g_arr)
    energy = _energy(m, com_l, up, energy_edges)

    return _report(tractor, load, thresholds, loads, margins, energy)  # the same report as evaluate_stability


def _support(tractor: Tractor, p: list[float], g: list[float], g_arr: np.ndarray) -> SupportMargins:
    """SSM and LSM [m] of the CoM ``p``: ``stability._support_margins`` in floats."""
    V0, n, e1, e2, edges = _support_floats(tractor)
    denom = _dot3(n, g)
    if abs(denom) < 1e-9:
        raise StabilityInputError("slope: gravity is parallel to the support plane; no projection exists")
    s = _dot3(n, [V0[0] - p[0], V0[1] - p[1], V0[2] - p[2]]) / denom
    q = [p[0] + s * g[0], p[1] + s * g[1], p[2] + s * g[2]]
    u = [q[0] - V0[0], q[1] - V0[1], q[2] - V0[2]]
    q2 = (_dot3(u, e1), _dot3(u, e2))
    d = [mm[0] * (q2[0] - va[0]) + mm[1] * (q2[1] - va[1]) for va, mm, _ in edges]
    if min(d) > 0:
        ssm = min(d)
    else:  # outside: the reference's distance to the triangle
        V2 = _support_constants(tractor)[4]
        q2a = np.array(q2)
        ssm = -min(_segment_distance(q2a, V2[a], V2[b]) for a, b, _ in _EDGES)
    lsm_front, lsm_rear = _travel_margins(d, [mv for _, _, mv in edges], ssm)
    qa = np.array(q)
    qa.setflags(write=False)
    return SupportMargins(qa, (d[0], d[1], d[2]), float(ssm), float(lsm_front), float(lsm_rear))


def _energy(m: float, p: list[float], up: list[float], edges: tuple) -> EnergyMargins:
    """Per-edge tip-over energies [J]: ``stability._energy_margins`` in floats."""
    out = []
    for A, axis, lift, side in edges:
        r = [p[0] - A[0], p[1] - A[1], p[2] - A[2]]
        ra = _dot3(r, axis)
        rp = [r[0] - ra * axis[0], r[1] - ra * axis[1], r[2] - ra * axis[2]]
        rise = math.sqrt(_dot3(rp, rp)) * lift - _dot3(rp, up)
        sr = _dot3(side, r)
        sign = 1.0 if sr > 0 else -1.0 if sr < 0 else 0.0 if sr == 0 else math.nan
        out.append(sign * m * STANDARD_GRAVITY * max(0.0, rise))
    return EnergyMargins((out[0], out[1], out[2]))
