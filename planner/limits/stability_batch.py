"""Stability measures for many implement poses at once (vectorised over N samples of a plan).

:func:`evaluate_stability_batch` computes, for N implement poses ``T`` (N, 3) [m] and
``R_i`` (N, 3, 3), the measures :func:`planner.limits.stability.evaluate_stability` gives per
pose: front-axle load [N], SSM [m], LSM [m] and ESM [J].  It follows the same formulas in the
same order (build_load_case -> axle_loads, support_margins, energy_margins; see that module
for conventions and sources) with the pose-independent parts (gravity, support frame, edge
axes) taken from it, so the meaning cannot drift.

Results agree with the per-sample function to rounding (its dot products of 3-vectors, here
matrix-vector products and einsum over all poses), not bit for bit.  Each result therefore carries ``tolerance``: a
bound per measure on |batch - per-sample| (10^4 times and more the rounding seen in tests),
and the samples where the batch cannot vouch for that bound (``suspect``): inputs the
per-sample function would reject (non-finite, rotation not proper within its 1e-6),
non-finite values, and samples next to a jump of a measure: LSM where the travel line just
crosses or misses the triangle, ESM where the CoM is next to the vertical plane through an
edge.  A caller that must decide exactly as the per-sample function (the guard) re-evaluates
those samples, and any whose value lies within ``tolerance`` of a threshold, with
:func:`~planner.limits.stability.evaluate_stability`.

Without an implement the measures do not depend on the pose: they are evaluated once with the
per-sample function and broadcast, and ``exact`` is True.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.limits.stability import (
    _EDGES,
    _energy_constants,
    _support_constants,
    evaluate_stability,
    gravity_direction,
)
from planner.limits.tractor import STANDARD_GRAVITY, ImplementRecord, StabilityInputError, Tractor, _scalar

__all__ = ["MEASURE_NAMES", "StabilityBatch", "cross_rows", "evaluate_stability_batch"]

#: Measure names, in the order of :attr:`StabilityBatch.values` columns (as the guard names them).
MEASURE_NAMES: tuple[str, str, str, str] = ("front_axle_load", "ssm", "lsm", "esm")
#: Relative size of the agreement bound (rounding is ~1e-15 of the same scales).
_REL_TOL = 1e-11
#: Rotation check of the per-sample function (tractor._rotation), and the margin kept to it.
_ORTHO_TOL = 1e-6


@dataclass(frozen=True)
class StabilityBatch:
    """Measures for N poses.  Arrays (N,); units N (front_axle_load), m (ssm, lsm), J (esm).

    ``tolerance``: per measure, a bound on |value - evaluate_stability value| for samples not
    ``suspect`` (same units).  ``exact``: the values are the per-sample function's, bit for bit.
    """

    front_axle_load: np.ndarray
    ssm: np.ndarray
    lsm: np.ndarray
    esm: np.ndarray
    suspect: np.ndarray
    tolerance: dict[str, float]
    exact: bool = False

    @property
    def values(self) -> np.ndarray:
        """(N, 4) columns in :data:`MEASURE_NAMES` order."""
        return np.column_stack([getattr(self, m) for m in MEASURE_NAMES])


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (N, k) with (N, k) or (k,) (one call: matrix-vector product or einsum)."""
    return a @ b if b.ndim == 1 else np.einsum("ij,ij->i", a, b)


def _norm(a: np.ndarray) -> np.ndarray:
    return np.sqrt(_dot(a, a))


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays: np.cross's products and differences (the same
    values, bit for bit) without its axis handling (~25 µs a call for a plan's samples)."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.column_stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _pose_suspect(T: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Poses the per-sample function might reject (tractor._vector3 / _rotation), with margin:
    the Gram matrix R^T R off the identity, the determinant (triple product of the columns)."""
    with np.errstate(invalid="ignore", over="ignore"):
        finite = np.isfinite(T).all(axis=1) & np.isfinite(R).all(axis=(1, 2))
        Rf = np.where(finite[:, None, None], R, 0.0)
        ortho = np.abs(np.matmul(Rf.transpose(0, 2, 1), Rf) - np.eye(3)).max(axis=(1, 2))
        c0, c1, c2 = Rf[:, :, 0], Rf[:, :, 1], Rf[:, :, 2]
        det = np.einsum("ij,ij->i", cross_rows(c0, c1), c2)
    return ~finite | ~(ortho <= 0.5 * _ORTHO_TOL) | ~(det > 0.5)


def evaluate_stability_batch(
    tractor: Tractor,
    implement: ImplementRecord | None,
    T,
    R_i,
    slope_roll: float,
    slope_pitch: float,
    *,
    front_ballast: float = 0.0,
) -> StabilityBatch:
    """Front-axle load [N], SSM [m], LSM [m], ESM [J] for N implement poses on one slope.

    ``T`` (N, 3) [m] tool points and ``R_i`` (N, 3, 3) implement rotations in the tractor frame;
    slopes [rad] and ``front_ballast`` [kg] as for
    :func:`~planner.limits.stability.evaluate_stability`.  Raises StabilityInputError for a
    slope, ballast or tractor the per-sample function rejects; see :class:`StabilityBatch`.
    """
    T = np.asarray(T, dtype=float)
    R_i = np.asarray(R_i, dtype=float)
    if T.ndim != 2 or T.shape[1] != 3 or R_i.shape != (T.shape[0], 3, 3):
        raise StabilityInputError(f"T must be (N, 3) and R_i (N, 3, 3), got {T.shape} and {R_i.shape}")
    n = T.shape[0]
    if implement is None or n == 0:
        # the per-sample measures ignore the pose: evaluate once, broadcast (exactly its values)
        rep = evaluate_stability(tractor, None, None, None, slope_roll, slope_pitch, front_ballast=front_ballast)
        return StabilityBatch(
            front_axle_load=np.full(n, rep.axle_loads.front),
            ssm=np.full(n, rep.ssm),
            lsm=np.full(n, rep.lsm),
            esm=np.full(n, rep.esm),
            suspect=np.zeros(n, bool),
            tolerance=dict.fromkeys(MEASURE_NAMES, 0.0),
            exact=True,
        )

    g = gravity_direction(slope_roll, slope_pitch)
    ballast = _scalar("front_ballast", front_ballast, 0.0, 20_000.0)
    suspect = _pose_suspect(T, R_i)

    # build_load_case: p_i = T + R_i c_i, combined mass and CoM
    c = np.asarray(implement.centre_of_mass, dtype=float)
    with np.errstate(invalid="ignore", over="ignore"):
        p_i = T + (R_i[:, :, 0] * c[0] + R_i[:, :, 1] * c[1] + R_i[:, :, 2] * c[2])
    m = tractor.mass + ballast
    moment = tractor.mass * tractor.centre_of_mass + ballast * tractor.front_ballast_point
    m_i = implement.mass
    m += m_i
    p = (moment + m_i * p_i) / m

    # axle_loads
    W = m * STANDARD_GRAVITY * g
    front = ((p[:, 1] - tractor.rear_axle[1]) * W[2] - (p[:, 2] - tractor.ground_z) * W[1]) / tractor.wheelbase

    # support_margins (its pose-independent part: frame, edges)
    V, nrm, e1, e2, V2, edges = _support_constants(tractor)
    denom = float(nrm @ g)
    if abs(denom) < 1e-9:
        raise StabilityInputError("slope: gravity is parallel to the support plane; no projection exists")
    q = p + (_dot(V[0] - p, nrm) / denom)[:, None] * g
    q2 = (q - V[0]) @ np.column_stack([e1, e2])
    s_lo, s_hi = np.full(n, -math.inf), np.full(n, math.inf)
    misses = np.zeros(n, bool)
    branch_near = np.zeros(n, bool)
    # length scale of every point involved [m]: the agreement bounds are relative to it
    reach = float(np.max(np.where(np.isfinite(T), np.abs(T), 0.0))) + float(np.linalg.norm(c))
    length = 1.0 + max(
        float(np.max(np.abs(V))),
        float(np.max(np.abs(tractor.centre_of_mass))),
        float(np.max(np.abs(tractor.front_ballast_point))),
        reach,
    )
    Va = np.array([e[0] for e in edges])  # (3, 2) edge start, inward unit normal, end - start
    M = np.array([e[1] for e in edges])
    AB = V2[[b for _, b, _ in _EDGES]] - V2[[a for a, _, _ in _EDGES]]
    rel = q2[:, None, :] - Va  # (N, 3, 2)
    D = np.einsum("nek,ek->ne", rel, M)  # signed distances to the edge lines
    mv_min = 1.0
    for i, (_, _, mv) in enumerate(edges):
        di = D[:, i]
        if abs(mv) < 1e-12:
            misses |= di < 0
            branch_near |= np.abs(di) <= _REL_TOL * length / abs(denom)
        elif mv > 0:
            s_lo = np.maximum(s_lo, -di / mv)
            mv_min = min(mv_min, abs(mv))
        else:
            s_hi = np.minimum(s_hi, -di / mv)
            mv_min = min(mv_min, abs(mv))
    s = np.minimum(1.0, np.maximum(0.0, np.einsum("nek,ek->ne", rel, AB) / np.einsum("ek,ek->e", AB, AB)))
    off = rel - s[:, :, None] * AB
    seg = np.sqrt(np.einsum("nek,nek->ne", off, off))  # distances to the edge segments
    dmin = np.minimum(np.minimum(D[:, 0], D[:, 1]), D[:, 2])
    ssm = np.where(dmin > 0, dmin, -np.minimum(np.minimum(seg[:, 0], seg[:, 1]), seg[:, 2]))
    tol_len = _REL_TOL * length / (abs(denom) * mv_min)
    branch_near |= np.abs(s_lo - s_hi) <= 2 * tol_len
    lsm = np.where(misses | (s_lo > s_hi), ssm, np.minimum(-s_lo, s_hi))

    # energy_margins (per edge: start, unit axis, sqrt(1 - (axis . up)^2), vertical plane normal)
    up = -g
    A, AX, LIFT, SIDE = (np.array(x) for x in zip(*_energy_constants(tractor, up), strict=True))
    r = p[:, None, :] - A  # (N, 3, 3)
    r_perp = r - np.einsum("nek,ek->ne", r, AX)[:, :, None] * AX
    rise = np.sqrt(np.einsum("nek,nek->ne", r_perp, r_perp)) * LIFT - r_perp @ up
    side_r = np.einsum("nek,ek->ne", r, SIDE)
    # the sign of side.r switches E between +-rise; it jumps there when the CoM is below the edge
    branch_near |= (np.abs(side_r) <= _REL_TOL * length).any(axis=1)
    energies = np.sign(side_r) * m * STANDARD_GRAVITY * np.maximum(0.0, rise)
    esm = np.minimum(np.minimum(energies[:, 0], energies[:, 1]), energies[:, 2])

    weight_scale = m * STANDARD_GRAVITY * length
    tolerance = {
        "front_axle_load": _REL_TOL * weight_scale * (1.0 + 1.0 / tractor.wheelbase),
        "ssm": tol_len,
        "lsm": tol_len,
        "esm": _REL_TOL * weight_scale,
    }
    values = np.column_stack([front, ssm, lsm, esm])
    suspect = suspect | branch_near | ~np.isfinite(values).all(axis=1)
    return StabilityBatch(front, ssm, lsm, esm, suspect=suspect, tolerance=tolerance)
