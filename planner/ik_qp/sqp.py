"""The SQP inverse-kinematics solver: one QP per iteration, ℓ1-merit line search.

Iteration ``k`` at actuators ``q``:

1. evaluate the task ``t``, error ``e``, constraints ``c = (h, g, t_bounded)``, their
   Jacobians and the Gauss–Newton terms ``JᵀW²J``, ``JᵀW²e`` in one buffered CasADi call;
2. solve one QP in the step ``d``::

       min ½‖W (J d − e)‖² + ½ λ_k ‖d‖² (+ ½ dᵀS d)   (Levenberg–Marquardt, λ_k = μ_k ‖W e‖)
       s.t. h + H d = 0,  g_lower <= g + G d <= g_upper,  b_lower <= t + J_b d <= b_upper,
            max(lower − q, −max_step) <= d <= min(upper − q, max_step);

   posed in units of the expected step so that the backend's tolerances are relative;
   when the linearisation is infeasible (far from the constraint set) an elastic QP with
   ℓ1-penalised slacks replaces it (restoration);
3. globalise: backtracking line search on the exact-penalty merit
   ``M(q) = ‖W e(q)‖ + ν ‖violation(q)‖₁``, with a second-order correction against the
   Maratos effect; a point where the mechanism gives non-finite values is rejected;
4. adapt ``μ`` to the ratio of actual to predicted decrease.

``λ_k = μ_k ‖W e_k‖`` vanishes with the error, so reachable targets converge
quadratically. Unreachable ones converge to a stationary point of ``‖W e‖`` on the
feasible set (status ``"limited"``, binding limits named from the QP multipliers) — or so
do reachable ones that stop in a local minimum: on a mechanism with several IK solutions (a
serial arm, ``Mechanism.several_solutions``) the reason says "a local minimum or out of reach", a
local solver cannot tell the two apart; where
Gauss–Newton is only linear there (large residual, curved active limits) a secant estimate
``S`` of the missing Lagrangian curvature (:class:`~planner.ik_qp.mechanism.LagrangianCurvature`)
is added, and dropped again whenever it misleads. A solver is stateful (warm starts,
persistent QPs) and not thread-safe: use one per thread.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from planner.ik_qp.backends import QP_INFINITY, QPBackend, QPData, make_backend
from planner.ik_qp.errors import IKInputError
from planner.ik_qp.mechanism import LagrangianCurvature, LinearisationPoint, Mechanism
from planner.ik_qp.problem import IKProblem, IKSolution, Status, check_vector
from planner.model.limit_names import LimitName

__all__ = ["SQPSolver", "SQPSettings"]

#: Per-iteration trust region cap, in expected step sizes ``s`` (see ``SQPSolver._step``).
_TRUST_CAP = 1e6


@dataclass(frozen=True)
class SQPSettings:
    """Tolerances and limits of :class:`SQPSolver` (task, constraint and actuator units).

    Attributes:
        tol: Stop when the weighted residual ``‖W e‖ <= tol`` and constraints are met.
        reach_tol: Status ``"ok"`` iff the final residual is ``<= reach_tol``.
        constraint_tol: Constraints count as met for stopping when every violation is below it.
        feasibility_tol: A point is feasible (``"ok"``/``"limited"``) iff its largest
            violation is below it; otherwise the result is ``"failed"``.
        step_tol: Stationary when ``‖d‖∞ <= step_tol · max(1, ‖q‖∞)``.
        active_tol: A limit is at its bound within this distance (constraint units).
        max_iterations: SQP iterations (one main QP each).
        max_backtracks: Halvings of the step in one line search.
        armijo: Sufficient-decrease fraction of the predicted merit decrease.
        min_damping, max_damping: Range of the Levenberg–Marquardt factor ``μ``.
    """

    tol: float = 1e-10
    reach_tol: float = 1e-9
    constraint_tol: float = 1e-12
    feasibility_tol: float = 1e-9
    step_tol: float = 1e-12
    active_tol: float = 1e-9
    max_iterations: int = 100
    max_backtracks: int = 30
    armijo: float = 1e-4
    min_damping: float = 1e-9
    max_damping: float = 1e9

    def __post_init__(self) -> None:
        for name, v in vars(self).items():
            if name in ("max_iterations", "max_backtracks"):
                if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                    raise IKInputError(f"{name}: must be an integer >= 1, got {v!r}")
            elif isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise IKInputError(f"{name}: must be a finite number > 0, got {v!r}")
        if not self.armijo < 0.5:
            raise IKInputError(f"armijo: must be in (0, 0.5), got {self.armijo!r}")
        if self.min_damping > self.max_damping:
            raise IKInputError("min_damping: must not exceed max_damping")


@dataclass(frozen=True)
class _QPStep:
    """One solved QP at the current point (:meth:`SQPSolver._step`).

    Attributes:
        d: Step ``(n,)`` [actuator units].
        y: Multipliers ``(n + k,)`` of the box rows and the constraint rows ``c`` (OSQP signs,
            in the units of the unscaled QP).
        v_lin: ℓ1 violation of the linearised constraints ``c + C d`` [constraint units];
            0 for the main QP (it meets them).
        elastic: The step comes from the restoration (elastic) QP.
        scale: Expected step size ``s`` the QP was posed in (``d / s`` is O(1)) [actuator units].
    """

    d: np.ndarray
    y: np.ndarray
    v_lin: float
    elastic: bool
    scale: float


@dataclass(frozen=True)
class _MeritModel:
    """The exact-penalty merit of one iteration, ``M(q) = ‖W e(q)‖ + ν ‖violation(q)‖₁``.

    Attributes:
        value: ``M`` at the current point [weighted task units].
        predicted: Decrease of ``M`` the QP model predicts for the full step (none left: stationary).
        penalty: ``ν`` [weighted task units per constraint unit].
    """

    value: float
    predicted: float
    penalty: float

    def at(self, point: LinearisationPoint) -> float:
        """``M`` at a loaded point."""
        return point.res + self.penalty * point.v1


@dataclass(frozen=True)
class _LimitReport:
    """Limit names at the solution: ``at_bound`` within ``active_tol``; ``active`` also carry a
    multiplier pushing against the bound (those that stop an out-of-reach target)."""

    active: tuple[str, ...]
    at_bound: tuple[str, ...]


class _Layout:
    """Everything fixed by the mechanism and the set of task-bound rows: constraint rows
    ``c = (h, g, t[rows])`` with bounds ``cl <= c <= cu``, the limit names of each side,
    the two linearisation points (current/trial) and the QP buffers."""

    def __init__(self, mech: Mechanism, rows: np.ndarray, label: str):
        n, self.p, self.r = mech.n, mech.p, mech.r
        self.rows = rows
        self.k = k = self.p + self.r + rows.size
        tasks = [mech.task_names[i] for i in rows.tolist()]
        # inequality rows keep the mechanism's own names (any string); task bounds and actuator
        # bounds are named as LimitName spells them: <label>:<task>:min|max and
        # <kind>:<actuator>:min|max, kind "stroke" (the hitch's cylinders) unless the mechanism
        # says otherwise (a serial arm: "joint", Mechanism.limit_kind)
        kind = mech.limit_kind
        side = list(mech.limit_names()) + [
            (str(LimitName(label, t, "min")), str(LimitName(label, t, "max"))) for t in tasks
        ]
        # Indexed like the QP rows (actuator bounds, equalities, inequalities, task bounds);
        # equalities are no limits and have no names.
        self.names_min = (
            tuple(str(LimitName(kind, a, "min")) for a in mech.actuator_names)
            + ("",) * self.p
            + tuple(s[0] for s in side)
        )
        self.names_max = (
            tuple(str(LimitName(kind, a, "max")) for a in mech.actuator_names)
            + ("",) * self.p
            + tuple(s[1] for s in side)
        )
        self.row_names = mech.equality_names + mech.inequality_names + tuple(str(LimitName(label, t)) for t in tasks)
        self.cl = np.concatenate([np.zeros(self.p), mech.g_lower, np.zeros(rows.size)])
        self.cu = np.concatenate([np.zeros(self.p), mech.g_upper, np.zeros(rows.size)])
        fn = mech.linearisation_function(rows.tolist())
        self.points = (LinearisationPoint(mech, fn), LinearisationPoint(mech, fn))
        self.curvature = LagrangianCurvature(n)
        self.main = QPData(n, n + k)
        self.elastic = el = QPData(n + k, n + 3 * k)
        el.A[n + k : n + 2 * k, n:] = np.eye(k)
        el.A[n + 2 * k :, n:] = -np.eye(k)
        el.l[n : n + k], el.u[n : n + k] = 0.0, QP_INFINITY
        el.u[n + k : n + 2 * k], el.l[n + 2 * k :] = QP_INFINITY, -QP_INFINITY

    def set_problem(self, problem: IKProblem) -> None:
        """Bind the target, weights and (changing) task-bound values of ``problem``."""
        tb = problem.task_bounds
        if tb is not None and self.rows.size:
            pr = self.p + self.r
            self.cl[pr:], self.cu[pr:] = tb.lower[self.rows], tb.upper[self.rows]
        for point in self.points:
            point.set_problem(problem.target, problem.weights, self.cl, self.cu, problem.max_step)


class SQPSolver:
    """SQP inverse kinematics on one :class:`Mechanism`, with persistent QP objects and warm starts.

    Args:
        mechanism: The mechanism (fixed for the solver's lifetime).
        backend: QP backend, one of ``"osqp"`` (default; one persistent ``osqp.OSQP`` per
            problem shape), ``"daqp"``, ``"quadprog"``, ``"proxqp"``, ``"clarabel"``.
        settings: Base :class:`SQPSettings`; keyword ``overrides`` (``tol=...``,
            ``max_iterations=...``, any settings field) replace single fields.
        backend_options: Extra options passed to the QP backend.

    ``solve(problem, seed=None)`` starts from ``seed`` or, when ``None``, from the last
    solution (streaming targets along a path), or from the middle of the strokes.
    """

    def __init__(
        self,
        mechanism: Mechanism,
        *,
        backend: str = "osqp",
        settings: SQPSettings | None = None,
        backend_options: dict[str, Any] | None = None,
        **overrides: Any,
    ):
        if not isinstance(mechanism, Mechanism):
            raise IKInputError(f"mechanism: expected a Mechanism, got {type(mechanism).__name__}")
        if settings is not None and not isinstance(settings, SQPSettings):
            raise IKInputError(f"settings: expected SQPSettings, got {type(settings).__name__}")
        unknown = set(overrides) - set(SQPSettings.__dataclass_fields__)
        if unknown:
            raise IKInputError(
                f"SQPSolver: unknown setting(s) {sorted(unknown)}; allowed: "
                f"{', '.join(SQPSettings.__dataclass_fields__)}"
            )
        self.settings: SQPSettings = replace(settings or SQPSettings(), **overrides)
        self.mechanism = mechanism
        self.backend: QPBackend = make_backend(backend, **(backend_options or {}))
        self._layouts: dict[tuple[tuple[int, ...], str], _Layout] = {}
        self.last_q: np.ndarray | None = None
        lo, hi = mechanism.lower, mechanism.upper
        both = np.isfinite(lo) & np.isfinite(hi)
        self._mid = np.clip(np.where(both, 0.5 * (np.where(both, lo, 0.0) + np.where(both, hi, 0.0)), 0.0), lo, hi)
        self._q_try = np.zeros(mechanism.n)

    def reset(self) -> None:
        """Forget the last solution (the next solve without seed starts mid-stroke)."""
        self.last_q = None

    def solve(self, problem: IKProblem, seed: ArrayLike | None = None) -> IKSolution:
        """Solve ``problem`` from ``seed`` (``(n,)``, clipped into the strokes), else from the
        last solution, else from mid-stroke."""
        t_start = time.perf_counter()
        if not isinstance(problem, IKProblem):
            raise IKInputError(f"problem: expected an IKProblem (see build_ik_problem), got {type(problem).__name__}")
        if problem.mechanism is not self.mechanism:
            raise IKInputError(
                f"problem: built for mechanism {problem.mechanism.name!r}, this solver is for {self.mechanism.name!r}"
            )
        st = self.settings
        lay = self._layout(problem)
        cur, trial = lay.points
        if not self._start(seed, cur):
            return self._no_valid_point(seed, t_start)
        mu, nu, it = problem.damping, 1.0, 0
        n = self.mechanism.n
        curv, use_curv, d_prev = lay.curvature, False, math.inf
        curv.reset()
        y_last: np.ndarray | None = None
        stationary, reason = False, ""
        while True:
            if cur.res <= st.tol and cur.vinf <= st.constraint_tol:
                break
            if it >= st.max_iterations:
                reason = f"iteration limit ({st.max_iterations}) reached"
                break
            it += 1
            step = self._step(problem, lay, cur, mu * cur.res, curv.S if use_curv else None)
            if step is None:
                if use_curv:
                    use_curv = False
                    continue
                mu = min(mu * 10.0, st.max_damping)
                if mu >= st.max_damping:
                    reason = f"QP backend {self.backend.name!r} failed at every damping"
                    break
                continue
            d, y_last = step.d, step.y
            # ‖W (e − J d)‖ of the quadratic model (Gauss–Newton terms, plus S when used).
            quad = d @ cur.H0 @ d + (d @ curv.S @ d if use_curv else 0.0)
            model = math.sqrt(max(cur.res * cur.res - 2.0 * (cur.g @ d) + quad, 0.0))
            increase, drop = model - cur.res, cur.v1 - step.v_lin
            if use_curv and increase > 0.0:  # S made a poor model: back to Gauss–Newton
                use_curv = False
                curv.reset()
                continue
            if drop > 0.0 and increase > 0.0:
                nu = max(nu, 2.0 * increase / drop)
            merit = _MeritModel(cur.res + nu * cur.v1, nu * max(drop, 0.0) - increase, nu)
            d_norm = float(np.abs(d).max())
            if d_norm <= st.step_tol * max(1.0, cur.q_inf) or merit.predicted <= 1e-15 * max(merit.value, 1e-300):
                stationary = True
                break
            alpha = self._line_search(lay, cur, trial, step, merit)
            if alpha > 0.0:
                cur, trial = trial, cur
                if use_curv and alpha < 1.0:  # the curvature estimate misleads: Gauss–Newton
                    use_curv = False
                    curv.reset()
                elif alpha == 1.0 and d_norm > 0.1 * d_prev and float(np.abs(d / problem.max_step).max()) < 0.5:
                    # Local, linear convergence to a non-zero residual (out of reach, curved
                    # active limits): learn and use the curvature Gauss–Newton misses.
                    curv.update(cur, trial, step.y[n:])
                    use_curv = curv.pairs > 0 and cur.res > 0.3 * trial.res
                d_prev = d_norm
                if alpha < 1.0:
                    mu = min(mu * 4.0, st.max_damping)
                elif merit.value - merit.at(cur) > 0.75 * merit.predicted:
                    mu = max(mu * 0.25, st.min_damping)
            elif use_curv:  # the curvature estimate misled: back to Gauss–Newton
                use_curv = False
                curv.reset()
            elif merit.predicted <= 1e-10 * merit.value:  # no decrease possible at working precision
                stationary = True
                break
            else:
                mu = min(mu * 10.0, st.max_damping)
        self.last_q = cur.q.copy()
        return self._finish(problem, lay, cur, y_last, it, stationary, reason, t_start)

    # ------------------------------------------------------------------ pieces
    def _layout(self, problem: IKProblem) -> _Layout:
        tb = problem.task_bounds
        rows = tb.rows if tb is not None else np.zeros(0, dtype=np.intp)
        label = tb.label if tb is not None else ""
        key = (tuple(rows.tolist()), label)
        lay = self._layouts.get(key)
        if lay is None:
            lay = self._layouts[key] = _Layout(self.mechanism, rows, label)
        lay.set_problem(problem)
        return lay

    def _start(self, seed: ArrayLike | None, cur: LinearisationPoint) -> bool:
        """Load the first valid start among the seed (or the last solution) and mid-stroke."""
        mech = self.mechanism
        candidates: list[np.ndarray] = []
        if seed is not None:
            candidates.append(check_vector(seed, mech.n, "seed").copy())
        elif self.last_q is not None:
            candidates.append(self.last_q.copy())
        candidates.append(self._mid.copy())
        return any(cur.load(self._clip(c)) for c in candidates)

    def _clip(self, q: np.ndarray) -> np.ndarray:
        """``q`` clipped into the strokes, in place (np.clip costs ~3 µs, this ~0.7 µs)."""
        np.maximum(q, self.mechanism.lower, out=q)
        return np.minimum(q, self.mechanism.upper, out=q)

    def _step(
        self, problem: IKProblem, lay: _Layout, cur: LinearisationPoint, lam: float, S: np.ndarray | None = None
    ) -> _QPStep | None:
        """Solve the QP at ``cur`` with damping ``lam`` (and curvature estimate ``S`` (n, n) when
        given): the step, or ``None`` when no QP could be solved.

        The QP is posed in ``d / s`` with ``s`` the expected step size, so its data are O(1)
        at every iteration and the backend's tolerances act relative to the step.
        """
        n, k = self.mechanism.n, lay.k
        qp = lay.main
        qp.P[:] = cur.H0
        qp.P_flat_f[:: n + 1] += lam + 1e-10 * (1.0 + cur.p_max)
        if S is not None:
            qp.P += S
            try:
                np.linalg.cholesky(qp.P)
            except np.linalg.LinAlgError:  # indefinite: floor the eigenvalues (convex QP)
                w, V = np.linalg.eigh(qp.P)
                qp.P[:] = (V * np.maximum(w, 1e-6 * (1.0 + cur.p_max))) @ V.T
        scale = cur.g_inf / (cur.p_max + lam + 1e-300)
        if k:
            qp.A[n:] = cur.C
            if cur.vinf > 0.0:
                scale = max(scale, cur.vinf / (cur.c_inf + 1e-300))
        scale = min(max(scale, 1e-30), problem.max_step.max())
        inv = 1.0 / scale
        np.multiply(cur.g, -inv, out=qp.c)
        np.multiply(cur.l0, inv, out=qp.l)
        np.multiply(cur.u0, inv, out=qp.u)
        # Trust region at most TRUST_CAP expected steps: keeps every QP's data within a few
        # orders of magnitude (interior-point backends lose accuracy on 1e10 bounds).
        np.maximum(qp.l[:n], -_TRUST_CAP, out=qp.l[:n])
        np.minimum(qp.u[:n], _TRUST_CAP, out=qp.u[:n])
        res = self.backend.solve(qp, "main")
        if res.solved:
            return _QPStep(res.x[:n] * scale, res.y * scale, 0.0, False, scale)
        if not k or S is not None or (res.status != "infeasible" and cur.vinf <= self.settings.feasibility_tol):
            return None  # numerical failure (or curvature step): no restoration
        # Restoration: elastic QP, slacks t >= 0 with |violation of c + C d| <= t, cost rho·Σt.
        el = lay.elastic
        el.P[:n, :n] = qp.P
        rho = 100.0 * (1.0 + cur.g_inf * inv)  # > the (scaled) multipliers: exact penalty
        el.P_flat_f[n * (n + k + 1) :: n + k + 1] = 1e-3 * (cur.p_max + lam)  # conditioning only
        el.c[:n], el.c[n:] = qp.c, rho
        el.l[:n], el.u[:n] = qp.l[:n], qp.u[:n]
        el.A[n + k : n + 2 * k, :n] = cur.C
        el.A[n + 2 * k :, :n] = cur.C
        el.l[n + k : n + 2 * k] = qp.l[n:]
        el.u[n + 2 * k :] = qp.u[n:]
        res = self.backend.solve(el, "elastic")
        if not res.solved:
            return None
        d = res.x[:n] * scale
        lin = cur.c + cur.C @ d
        v_lin = float(np.maximum(np.maximum(lay.cl - lin, lin - lay.cu), 0.0).sum())
        y = np.concatenate([res.y[:n], res.y[n + k : n + 2 * k] + res.y[n + 2 * k :]]) * scale
        return _QPStep(d, y, v_lin, True, scale)

    def _line_search(
        self, lay: _Layout, cur: LinearisationPoint, trial: LinearisationPoint, step: _QPStep, merit: _MeritModel
    ) -> float:
        """Backtracking on the merit with one second-order correction; the accepted point is
        left in ``trial``. Returns the step fraction, 0 on failure."""
        st = self.settings
        alpha = 1.0
        for _ in range(st.max_backtracks):
            q_try = self._q_try
            np.multiply(step.d, alpha, out=q_try)
            q_try += cur.q
            if trial.load(self._clip(q_try)):
                if merit.value - merit.at(trial) >= st.armijo * alpha * merit.predicted:
                    return alpha
                if alpha == 1.0 and lay.k and not step.elastic and trial.v1 > cur.v1:
                    q_soc = self._second_order_correction(lay, cur, trial, step)
                    if (
                        q_soc is not None
                        and trial.load(q_soc)
                        and merit.value - merit.at(trial) >= st.armijo * merit.predicted
                    ):
                        return 1.0
            alpha *= 0.5
        return 0.0

    def _second_order_correction(
        self, lay: _Layout, cur: LinearisationPoint, trial: LinearisationPoint, step: _QPStep
    ) -> np.ndarray | None:
        """Re-solve the QP with the constraints shifted by their curvature along ``step.d``
        (``c(q + d) − C d`` for ``c``): counters the Maratos effect (Nocedal & Wright §18.3)."""
        n, qp = self.mechanism.n, lay.main
        # trial.l0[n:] = cl − c(q + d), so cl − (c(q + d) − C d) = trial.l0[n:] + C d
        shift = cur.C @ step.d
        np.multiply(trial.l0[n:] + shift, 1.0 / step.scale, out=qp.l[n:])
        np.multiply(trial.u0[n:] + shift, 1.0 / step.scale, out=qp.u[n:])
        res = self.backend.solve(qp, "main", matrices_changed=False)
        if not res.solved:
            return None
        return self._clip(cur.q + res.x[:n] * step.scale)

    def _limits(self, lay: _Layout, cur: LinearisationPoint, y: np.ndarray | None, use_duals: bool) -> _LimitReport:
        """Limit names at ``cur``: at bound within ``active_tol``; active also needs a multiplier
        ``y`` of the last QP pushing against the bound."""
        mech, tol, n, p = self.mechanism, self.settings.active_tol, self.mechanism.n, lay.p
        lo = np.flatnonzero(cur.q - mech.lower <= tol).tolist()
        hi = np.flatnonzero(mech.upper - cur.q <= tol).tolist()
        if lay.k > p:  # inequality and task-bound rows (equalities are not limits)
            lo += (np.flatnonzero(cur.c[p:] - lay.cl[p:] <= tol) + n + p).tolist()
            hi += (np.flatnonzero(lay.cu[p:] - cur.c[p:] <= tol) + n + p).tolist()
        at_bound = tuple(lay.names_min[i] for i in lo) + tuple(lay.names_max[i] for i in hi)
        if not (use_duals and y is not None and at_bound):
            return _LimitReport((), at_bound)
        # Multipliers balance the task gradient JᵀW²e; much smaller ones are solver noise.
        noise = 1e-7 * max(float(np.abs(cur.g).max()), 1e-300)
        active = tuple(lay.names_min[i] for i in lo if y[i] < -noise)
        return _LimitReport(active + tuple(lay.names_max[i] for i in hi if y[i] > noise), at_bound)

    def _finish(
        self,
        problem: IKProblem,
        lay: _Layout,
        cur: LinearisationPoint,
        y: np.ndarray | None,
        iterations: int,
        stationary: bool,
        reason: str,
        t_start: float,
    ) -> IKSolution:
        st = self.settings
        status: Status
        if cur.vinf > st.feasibility_tol:
            status = "failed"
            worst = int(np.argmax(np.maximum(lay.cl - cur.c, cur.c - lay.cu)))
            reason = f"no feasible point found: {lay.row_names[worst]} violated by {cur.vinf:.3g}" + (
                f" ({reason})" if reason else " (locally infeasible)"
            )
        elif cur.res <= st.reach_tol:
            status, reason = "ok", "target reached"
        else:
            status = "limited"
        limits = self._limits(lay, cur, y, use_duals=status == "limited")
        active, at_bound = limits.active, limits.at_bound
        if status == "limited":
            reason = self._limited_reason(cur.res, active, stationary, reason)
        return IKSolution(
            q=cur.q.copy(),
            status=status,
            reason=reason,
            active=active,
            iterations=iterations,
            residual=float(cur.res),
            solve_time_s=time.perf_counter() - t_start,
            task=cur.t.copy(),
            error=cur.e.copy(),
            violation=float(cur.vinf),
            at_bound=at_bound,
        )

    def _limited_reason(self, residual: float, active: tuple[str, ...], stationary: bool, why: str) -> str:
        """The ``reason`` of a ``"limited"`` result at weighted residual ``residual`` with the binding
        limits ``active``; ``why`` says what stopped a solve that is not ``stationary``.

        A stationary point is the nearest reachable point only if the mechanism has one solution
        near it (the hitch). For a mechanism with several IK solutions (a serial arm,
        ``Mechanism.several_solutions``) it may be a local minimum of a reachable target: the reason
        says that a local solver cannot tell the two apart instead of claiming "out of reach"."""
        res = f"weighted residual {residual:.3g}"
        several, note = self.mechanism.several_solutions, self.mechanism.several_solutions_note
        if not stationary:
            text = f"{why or 'stopped'} before convergence, {res}"
            if active:
                return text + f"; stopped by {', '.join(active)}"
            return text + ("; no limit active" if several else "; no limit active (mechanism reach)")
        if not several:
            text = f"target out of reach: nearest reachable point, {res}"
            return text + (f"; stopped by {', '.join(active)}" if active else "; no limit active (mechanism reach)")
        where = (
            f"stopped at {'limit' if len(active) == 1 else 'limits'} {', '.join(active)} with {res}"
            if active
            else f"stationary with no limit active, {res}"
        )
        return f"{where}: a local minimum or out of reach (a local solver cannot tell{'; ' + note if note else ''})"

    def _no_valid_point(self, seed: ArrayLike | None, t_start: float) -> IKSolution:
        q = self._clip(self._mid.copy() if seed is None else np.array(seed, dtype=float).reshape(-1))
        return IKSolution.without_valid_start(self.mechanism, q, time.perf_counter() - t_start)
