"""Pose-space velocity, acceleration and jerk limits that keep every actuator within its limits.

A straight segment p(s) = p0 + s·u in pose space (x, z, roll, pitch) maps to actuators
q(s) through the exact inverse. Along the path q' = dq/ds = G(p)·u and q'' = dq'/ds, so
  q̇ = q'·ṡ,  q̈ = q'·s̈ + q''·ṡ²,  q⃛ = q'·s⃛ + 3q''·ṡ·s̈ + q'''·ṡ³.
The scalar limits (ṡ, s̈, s⃛) are the largest for which these stay within the actuator
limits at every one of K points of the path; per-DOF pose limits are the scalar ones
times |u_d|, so a phase-synchronised Ruckig profile moves exactly along the line.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from planner.model.exact_inverse import ExactInverse
from planner.trajectory.actuator_limits import ActuatorLimits
from planner.trajectory.plan import TrajectoryInputError

__all__ = ["PoseLimits", "straight_line_limits", "box_limits"]

_EPS = 1e-12


@dataclass(frozen=True)
class PoseLimits:
    """Per-DOF limits over (x, z, roll, pitch): units/s, /s², /s³."""

    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray

    def scaled(self, factor: float) -> PoseLimits:
        return PoseLimits(self.velocity * factor, self.acceleration * factor**2, self.jerk * factor**3)

    def floored(self, floor: PoseLimits) -> PoseLimits:
        return PoseLimits(
            np.maximum(self.velocity, floor.velocity),
            np.maximum(self.acceleration, floor.acceleration),
            np.maximum(self.jerk, floor.jerk),
        )


def straight_line_limits(
    inverse: ExactInverse, p0: ArrayLike, p1: ArrayLike, limits: ActuatorLimits, points: int = 24
) -> PoseLimits:
    """Pose limits for the straight segment p0 → p1 (both reachable; every point must be)."""
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    d = b - a
    length = float(np.linalg.norm(d))
    if length < _EPS:
        return box_limits(inverse, [a], limits)
    u = d / length
    s = np.linspace(0.0, length, points)
    jac = inverse.jacobians(np.array([a + si * u for si in s]))  # as inverse.solve(...)[1] of each point
    g = np.array([j @ u for j in jac])  # q'(s), (K, 5)
    h = np.gradient(g, s, axis=0)  # q''(s)
    k = np.gradient(h, s, axis=0)  # q'''(s)
    ag, ah, ak = np.abs(g) + _EPS, np.abs(h), np.abs(k)
    vs = float(np.min(limits.velocity / ag))
    # leave room for the curvature terms, then take what the first-order term allows
    vs = min(vs, float(np.min(np.sqrt(0.5 * limits.acceleration / np.maximum(ah, _EPS)))))
    as_ = float(np.min((limits.acceleration - ah * vs**2) / ag))
    js = float(np.min((limits.jerk - 3 * ah * vs * as_ - ak * vs**3) / ag))
    if js <= 0:
        f = 0.5
        vs, as_ = vs * f, as_ * f * f
        js = float(np.min((limits.jerk - 3 * ah * vs * as_ - ak * vs**3) / ag))
    au = np.abs(u)
    return PoseLimits(vs * au, as_ * au, max(js, _EPS) * au)


def box_limits(inverse: ExactInverse, points: Iterable[ArrayLike], limits: ActuatorLimits) -> PoseLimits:
    """Per-DOF pose limits valid in ANY direction at the given points: with |ṗ_d| ≤ v_d for
    all d, Σ_d |G_id|·v_d ≤ v_i for every actuator i (likewise for acceleration and jerk,
    with a factor 0.8 for the neglected curvature terms). Used for jog, stops and blends."""
    best: np.ndarray | None = None
    for p in points:
        G = np.abs(inverse.solve(np.asarray(p, float))[1])  # (5, 4)
        axis = np.min(limits.velocity[:, None] / (G + _EPS), axis=0)  # each DOF alone
        kappa = np.min(limits.velocity / (G @ axis + _EPS))
        cand = axis * kappa
        best = cand if best is None else np.minimum(best, cand)
    if best is None:
        raise TrajectoryInputError("box_limits: at least one point is needed")
    # acceleration and jerk in the same proportion as the actuators' own ratios
    ratio_a = float(np.min(limits.acceleration / limits.velocity)) * 0.8
    ratio_j = float(np.min(limits.jerk / limits.acceleration)) * 0.8
    return PoseLimits(best, best * ratio_a, best * ratio_a * ratio_j)
