"""An inverse-kinematics problem on a :class:`~planner.ik_qp.mechanism.Mechanism`, and its solution.

:func:`build_ik_problem` validates a target and its options into a frozen, inspectable
:class:`IKProblem`; :class:`~planner.ik_qp.sqp.SQPSolver` turns it into an :class:`IKSolution`.
All values are SI (m, rad, s) in the units of the mechanism's tasks and actuators.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import numpy as np

from planner.ik_qp.errors import IKInputError
from planner.ik_qp.mechanism import Mechanism

__all__ = [
    "DEFAULT_DAMPING",
    "IKProblem",
    "IKSolution",
    "TaskBounds",
    "build_ik_problem",
    "build_task_bounds",
    "check_vector",
    "default_max_step",
]

#: Initial Levenberg–Marquardt factor μ₀ (see :class:`IKProblem`).
DEFAULT_DAMPING = 1e-3

Status = Literal["ok", "limited", "failed"]


def _readonly(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


def check_vector(value, size: int, field_name: str, *, allow_inf: bool = False) -> np.ndarray:
    """A read-only float array of shape ``(size,)`` ((size, 1) and (1, size) accepted), all
    finite (or ±inf with ``allow_inf``); else ``ValueError`` naming ``field_name``."""
    if isinstance(value, (str, bytes)):
        raise IKInputError(f"{field_name}: expected {size} numbers, got a string")
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise IKInputError(f"{field_name}: expected {size} numbers, got {value!r}") from None
    if arr.shape != (size,):
        if arr.size == size and arr.ndim == 2 and 1 in arr.shape:
            arr = arr.reshape(-1)
        else:
            raise IKInputError(f"{field_name}: expected shape ({size},), got {arr.shape}")
    ok = not np.isnan(arr).any() if allow_inf else np.isfinite(arr).all()
    if not ok:
        i = int(np.flatnonzero(np.isnan(arr) if allow_inf else ~np.isfinite(arr))[0])
        allowed = "a number or ±inf" if allow_inf else "a finite number"
        raise IKInputError(f"{field_name}[{i}] must be {allowed}, got {arr[i]}")
    return _readonly(arr)


@dataclass(frozen=True, eq=False)
class TaskBounds:
    """Extra hard bounds ``lower <= t(q) <= upper`` on task values (e.g. a workspace box).

    Rows with both sides infinite are not constraints. Active sides are reported as
    ``<label>:<task name>:min|max`` (e.g. ``workspace:x:max``); the label has no ``:``.
    """

    lower: np.ndarray
    upper: np.ndarray
    label: str = "workspace"

    @cached_property
    def rows(self) -> np.ndarray:
        """Indices of the task rows with at least one finite side."""
        return np.flatnonzero(np.isfinite(self.lower) | np.isfinite(self.upper))


def build_task_bounds(
    mechanism: Mechanism,
    bounds: TaskBounds | Mapping[str, tuple[float, float]] | tuple,
    label: str = "workspace",
) -> TaskBounds:
    """Validate task bounds given as a :class:`TaskBounds`, a mapping ``{task name: (lo, hi)}``
    (missing rows are free) or a pair ``(lower (m,), upper (m,))``."""
    m = mechanism.m
    if isinstance(bounds, TaskBounds):
        lower, upper, label = bounds.lower, bounds.upper, bounds.label
    elif isinstance(bounds, Mapping):
        lower, upper = np.full(m, -np.inf), np.full(m, np.inf)
        for key, pair in bounds.items():
            if key not in mechanism.task_names:
                raise IKInputError(f"task_bounds: unknown task {key!r}; allowed: {', '.join(mechanism.task_names)}")
            try:
                lo, hi = (float(v) for v in pair)
            except (TypeError, ValueError):
                raise IKInputError(f"task_bounds[{key!r}]: expected (lower, upper) numbers, got {pair!r}") from None
            i = mechanism.task_names.index(key)
            lower[i], upper[i] = lo, hi
    else:
        try:
            lower, upper = bounds
        except (TypeError, ValueError):
            raise IKInputError("task_bounds: expected a mapping {task: (lo, hi)} or a pair (lower, upper)") from None
    lower = check_vector(lower, m, "task_bounds.lower", allow_inf=True)
    upper = check_vector(upper, m, "task_bounds.upper", allow_inf=True)
    bad = np.flatnonzero(lower > upper)
    if bad.size:
        i = int(bad[0])
        raise IKInputError(f"task_bounds[{mechanism.task_names[i]!r}]: lower {lower[i]} exceeds upper {upper[i]}")
    if not isinstance(label, str) or not label:
        raise IKInputError(f"task_bounds.label: must be a non-empty string, got {label!r}")
    if ":" in label:
        raise IKInputError(
            f"task_bounds.label: must not contain ':' (limits are named <label>:<task>:min|max), got {label!r}"
        )
    return TaskBounds(lower=lower, upper=upper, label=label)


@dataclass(frozen=True, eq=False)
class IKProblem:
    """One inverse-kinematics query, validated and inspectable.

    The SQP minimises ``½‖W e(q)‖²`` with ``W = diag(weights)`` and ``e = target − t(q)``
    (or the mechanism's ``task_error``) subject to the mechanism's equalities,
    inequalities, actuator bounds and the optional :class:`TaskBounds`.

    Attributes:
        mechanism: The mechanism.
        target: ``(m,)`` wanted task values (task units).
        weights: ``(m,)`` task weights ``>= 0``; 0 on inactive (free) tasks.
        active_tasks: ``(m,)`` boolean mask, ``weights > 0``.
        damping: Initial Levenberg–Marquardt factor ``μ₀`` (> 0). Iteration ``k`` damps the
            QP with ``λ_k = μ_k ‖W e_k‖`` (Fan–Yuan rule, so ``λ → 0`` and the final
            convergence on reachable targets is quadratic); ``μ_k`` adapts to the ratio of
            actual to predicted merit decrease. Units: weighted task / actuator².
        max_step: ``(n,)`` trust region ``|Δq_i| <= max_step_i`` per SQP iteration (actuator units).
        task_bounds: Optional extra bounds on the task values.
    """

    mechanism: Mechanism
    target: np.ndarray
    weights: np.ndarray
    active_tasks: np.ndarray
    damping: float
    max_step: np.ndarray
    task_bounds: TaskBounds | None = None

    @property
    def extra_bounds(self) -> TaskBounds | None:
        """Alias of :attr:`task_bounds` (the name of the original interface sketch)."""
        return self.task_bounds


def default_max_step(mechanism: Mechanism) -> np.ndarray:
    """The default trust region: see :attr:`Mechanism.default_max_step`."""
    return mechanism.default_max_step


def build_ik_problem(
    mechanism: Mechanism,
    target,
    weights=None,
    *,
    active_tasks=None,
    damping: float = DEFAULT_DAMPING,
    max_step=None,
    task_bounds=None,
) -> IKProblem:
    """Validate and assemble an :class:`IKProblem`.

    Args:
        mechanism: The mechanism.
        target: ``(m,)`` finite task values.
        weights: ``(m,)`` finite weights ``>= 0`` (default all 1).
        active_tasks: Optional ``(m,)`` boolean mask; inactive tasks get weight 0 (free).
        damping: Initial Levenberg–Marquardt factor ``μ₀``, finite and > 0.
        max_step: Scalar or ``(n,)`` positive trust region per iteration (default: a quarter
            of each stroke).
        task_bounds: ``None``, a :class:`TaskBounds`, ``{task name: (lo, hi)}`` or ``(lower, upper)``.

    Raises:
        ValueError: naming the offending field and its allowed range.
    """
    if not isinstance(mechanism, Mechanism):
        raise IKInputError(f"mechanism: expected a Mechanism, got {type(mechanism).__name__}")
    m, n = mechanism.m, mechanism.n
    target = check_vector(target, m, "target")
    w = np.ones(m) if weights is None else np.array(check_vector(weights, m, "weights"))
    if w.min() < 0:
        i = int(np.flatnonzero(w < 0)[0])
        raise IKInputError(f"weights[{i}] ({mechanism.task_names[i]}) must be >= 0, got {w[i]}")
    if active_tasks is not None:
        mask = np.array(active_tasks)
        if mask.shape != (m,) or mask.dtype != bool:
            raise IKInputError(f"active_tasks: expected a boolean mask of shape ({m},), got {mask.dtype} {mask.shape}")
        w[~mask] = 0.0
    if not w.max() > 0:
        raise IKInputError("weights: at least one task must have a positive weight")
    if (
        isinstance(damping, bool)
        or not isinstance(damping, (int, float, np.floating))
        or not np.isfinite(damping)
        or damping <= 0
    ):
        raise IKInputError(f"damping: must be a finite number > 0, got {damping!r}")
    if max_step is None:
        step = mechanism.default_max_step
    else:
        step = np.array(max_step, dtype=float) if np.ndim(max_step) else np.full(n, max_step, dtype=float)
        step = np.array(check_vector(step, n, "max_step"))
        if (step <= 0).any():
            i = int(np.flatnonzero(step <= 0)[0])
            raise IKInputError(f"max_step[{i}] ({mechanism.actuator_names[i]}) must be > 0, got {step[i]}")
    bounds = build_task_bounds(mechanism, task_bounds) if task_bounds is not None else None
    if bounds is not None and bounds.rows.size == 0:
        bounds = None
    return IKProblem(
        mechanism=mechanism,
        target=target,
        weights=_readonly(w),
        active_tasks=_readonly(w > 0),
        damping=float(damping),
        max_step=_readonly(step),
        task_bounds=bounds,
    )


@dataclass(frozen=True, eq=False)
class IKSolution:
    """Result of :meth:`~planner.ik_qp.sqp.SQPSolver.solve`.

    Attributes:
        q: ``(n,)`` actuators at the solution (always finite, always within the actuator bounds).
        status: ``"ok"`` target reached (``residual <= reach_tol``); ``"limited"`` target not
            reached, ``q`` is a feasible point where the solve stopped: a stationary point of the
            weighted task error on the feasible set (``reason`` says when the iteration limit
            stopped it first). On a mechanism with one solution near it (the hitch) that is the
            nearest reachable point in the weighted sense: the target is out of reach. On a
            mechanism with several IK solutions (a serial arm, ``several_solutions``) it may
            also be a local minimum of a *reachable* target (the SQP is a local solver), and
            ``reason`` says "a local minimum or out of reach" instead of claiming either (for the
            arm, :func:`planner.arm.analytic.solve_arm_ik` lists every solution).
            ``"failed"`` no feasible point found (``reason`` says why; ``q`` is the best point found).
        reason: Human-readable explanation.
        active: Names of the limits that stop the target (at their bound, non-zero multiplier):
            ``stroke:<actuator>:min|max`` (``joint:<joint>:min|max`` on a serial arm, the
            mechanism's ``limit_kind``), ``<inequality>:min|max`` (or the mechanism's
            side names), ``<label>:<task>:min|max``.
        iterations: SQP iterations (QP solves of the main problem).
        residual: ``‖W e(q)‖₂``, the weighted task error at ``q`` (task units).
        solve_time_s: Wall time of the solve [s].
        task: ``(m,)`` task values ``t(q)``.
        error: ``(m,)`` unweighted task error ``e(q)``.
        violation: Largest constraint violation at ``q`` (equalities, inequalities, task bounds).
        at_bound: Names of every limit at its bound (within tolerance), binding or not.
    """

    q: np.ndarray
    status: Status
    reason: str
    active: tuple[str, ...]
    iterations: int
    residual: float
    solve_time_s: float
    task: np.ndarray
    error: np.ndarray
    violation: float
    at_bound: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @classmethod
    def without_valid_start(cls, mechanism: Mechanism, q: np.ndarray, solve_time_s: float) -> IKSolution:
        """``"failed"``: the mechanism gives non-finite values at every start tried (``task`` and
        ``error`` are zeros, ``residual`` and ``violation`` inf: never NaN)."""
        return cls(
            q=q,
            status="failed",
            reason=f"{mechanism.name}: non-finite mechanism values at the start and at mid-stroke "
            "(no valid start point)",
            active=(),
            iterations=0,
            residual=math.inf,
            solve_time_s=solve_time_s,
            task=np.zeros(mechanism.m),
            error=np.zeros(mechanism.m),
            violation=math.inf,
        )
