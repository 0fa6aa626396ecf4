"""Inverse kinematics of the hitch: pose (x, z, roll, pitch) → five actuators, within every limit.

:class:`IKSolver` wraps the mechanism-agnostic SQP core (:mod:`planner.ik_qp.sqp`) with the
hitch mechanism (:mod:`planner.ik_qp.hitch_mechanism`): hard constraints are the strokes,
implement rigidity (thesis 2.49), top-link angles and ground clearance; the restricted
workspace is optional (off by default; the motion layers switch it on). It keeps the last
solution; each solve starts from the closed-form inverse clipped into the strokes
(``seed_strategy="closed_form"``, default: the SQP then only certifies it or, out of reach,
moves to the nearest reachable pose) or from the last solution (``"last"``). The hitch has
one solution per pose, so a small change of target gives a small change of actuators.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from planner.ik_qp.errors import IKInputError
from planner.ik_qp.hitch_mechanism import build_hitch_mechanism
from planner.ik_qp.problem import IKProblem, build_ik_problem
from planner.ik_qp.result import IKResult, Target, check_target
from planner.ik_qp.sqp import SQPSettings, SQPSolver
from planner.model.exact_inverse import ExactInverse
from planner.model.hard_limits import HardLimits
from planner.model.kinematics import HitchModel
from planner.model.types import Actuators, KinematicsError, Pose

__all__ = ["IKSolver", "default_weights", "BACKENDS"]

BACKENDS = ("osqp", "daqp", "quadprog", "proxqp", "clarabel")


def default_weights(model: HitchModel) -> np.ndarray:
    """Task weights (x, z, roll, pitch): 1 per metre of the tool point and d_T^U per radian,
    i.e. an angle counts as the displacement it causes at the mast top. Out-of-reach
    targets return the pose nearest in this metric."""
    return np.array([1.0, 1.0, model.mast_height, model.mast_height])


class IKSolver:
    """Constrained IK of one :class:`~planner.model.kinematics.HitchModel` (stateful: warm starts)."""

    def __init__(
        self,
        model: HitchModel,
        *,
        backend: str = "osqp",
        use_workspace: bool = False,
        settings: SQPSettings | None = None,
        limits: HardLimits | None = None,
        seed_strategy: str = "closed_form",
    ):
        if backend not in BACKENDS:
            raise IKInputError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        self.model = model
        self.limits = limits or HardLimits.from_model(model)
        self.mechanism = build_hitch_mechanism(model, self.limits)
        self.sqp = SQPSolver(self.mechanism, backend=backend, settings=settings or SQPSettings())
        self.use_workspace = use_workspace
        if use_workspace and model.workspace is None:
            raise IKInputError(
                f"use_workspace: profile {model.profile.name} has no restricted workspace for category {model.category}"
            )
        if seed_strategy not in ("closed_form", "last"):
            raise IKInputError(f"seed_strategy must be 'closed_form' or 'last', got {seed_strategy!r}")
        self.seed_strategy = seed_strategy
        self.inverse = ExactInverse(model)
        self.weights = default_weights(model)
        self.last = model.neutral.copy()
        self._problems: dict[tuple[bytes, bool], IKProblem] = {}

    def reset(self, actuators: ArrayLike | None = None) -> None:
        """Forget the warm start (next solve starts from ``actuators`` [rad, m, m, m, m] or the neutral pose);
        :class:`IKInputError` for anything but 5 finite values (a NaN was kept and seeded the next solve)."""
        self.last = self.model.neutral.copy() if actuators is None else self._actuator_values(actuators, "actuators")

    def solve(
        self,
        target: Target | Mapping[str, float] | Iterable[float],
        seed: Actuators | ArrayLike | None = None,
        *,
        use_workspace: bool | None = None,
    ) -> IKResult:
        """Solve for a :class:`~planner.ik_qp.result.Target` (or mapping / 4 numbers).

        ``seed``: actuators to start from (default: the last solution). Raises ValueError
        naming the field for NaN, inf or wrong types; never returns NaN.
        """
        t0 = time.perf_counter()
        x, z, roll, pitch = check_target(target)
        weights = self.weights
        if isinstance(target, Target) and target.weights is not None:
            weights = np.asarray(target.weights) * self.weights
        start = self._seed(seed) if seed is not None else self._default_seed(x, z, roll, pitch)
        ws = self.use_workspace if use_workspace is None else use_workspace
        if ws and self.model.workspace is None:
            return IKResult.failed("no restricted workspace for this category", 0, time.perf_counter() - t0)
        target_arr = np.array([x, z, roll, pitch])
        problem = self._problem(target_arr, weights, ws)
        sol = self.sqp.solve(problem, seed=start)
        if sol.status == "failed":
            return IKResult.failed(sol.reason, sol.iterations, time.perf_counter() - t0)
        try:
            f, _ = self.model.features(sol.q)
        except KinematicsError as exc:  # defensive: the core only returns closing points
            return IKResult.failed(f"solution does not close: {exc}", sol.iterations, time.perf_counter() - t0)
        self.last = sol.q.copy()
        pose = Pose.from_array(f[:6])
        err = pose.controlled() - target_arr
        return IKResult(
            actuators=Actuators.from_array(sol.q),
            pose=pose,
            status=sol.status,
            active=sol.active,
            iterations=sol.iterations,
            residual=float(np.max(np.abs(err))),
            solve_time_s=time.perf_counter() - t0,
            reason=sol.reason if sol.status != "ok" else "",
            extra={"weighted_residual": sol.residual, "at_bound": sol.at_bound, "violation": sol.violation},
        )

    def _problem(self, target: np.ndarray, weights: np.ndarray, use_workspace: bool) -> IKProblem:
        """The validated problem for these weights and bounds, reused with only the target replaced
        (the target was validated by :func:`check_target`)."""
        key = (weights.tobytes(), use_workspace)
        cached = self._problems.get(key)
        if cached is None:
            bounds = self.model.workspace if use_workspace else None
            cached = build_ik_problem(self.mechanism, target, weights, task_bounds=bounds)
            self._problems[key] = cached
            return cached
        return replace(cached, target=target)

    def _default_seed(self, x: float, z: float, roll: float, pitch: float) -> np.ndarray:
        """The closed-form inverse clipped into the strokes (then the SQP only certifies or
        corrects it), falling back to the last solution when the closed form has none."""
        if self.seed_strategy == "closed_form":
            try:
                q = self.inverse.solve(np.array([x, z, roll, pitch]))[0]
                return np.clip(q, self.limits.actuator_lower, self.limits.actuator_upper)
            except KinematicsError:
                pass
        return self.last

    def _seed(self, seed: Actuators | ArrayLike) -> np.ndarray:
        q = self._actuator_values(seed, "seed")
        return np.clip(q, self.limits.actuator_lower, self.limits.actuator_upper)

    @staticmethod
    def _actuator_values(value: Actuators | ArrayLike, what: str) -> np.ndarray:
        """``value`` as a new float vector of 5 finite actuator values, else :class:`IKInputError` naming ``what``."""
        try:
            q = value.as_array() if isinstance(value, Actuators) else np.array(value, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            q = np.full(0, np.nan)
        if q.size != 5 or not np.all(np.isfinite(q)):
            raise IKInputError(
                f"{what} must be 5 finite actuator values (lift [rad], tilt, top, left, right [m]), got {value!r}"
            )
        return q
