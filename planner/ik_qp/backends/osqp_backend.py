"""The default QP backend: one persistent ``osqp.OSQP`` per problem key and shape.

Each problem is ``setup()`` once with a fixed, fully dense sparsity pattern (upper
triangle of ``P``, all of ``A``), so later iterations only update its vectors and matrix
values (``update(q=, l=, u=, Px=, Ax=)``) and warm-start it (``warm_start(x=0)`` keeping
the last multipliers ``y``). (``qpsolvers.solve_qp(..., solver="osqp")`` would rebuild OSQP on every call,
~0.9 ms.)

Accuracy. ADMM stops at ``eps_abs = eps_rel = 1e-9`` (the SQP poses its QPs scaled to the
expected step, so that is relative to the step). When a non-equality row is active the
result is *polished*: the KKT system of the active set OSQP identified is solved densely
and accepted only if primal feasible with correctly signed multipliers (a few active-set
corrections are tried), else the ADMM solution stands. This replaces OSQP's own
polishing, which prints to stdout on every solve without active constraints even with
``verbose=False`` (osqp issue #785) and can accept a polished point far outside tolerance
(osqp issue #790). ``alpha = 1`` (no over-relaxation) measured 4x fewer ADMM iterations
than the default 1.6 on the warm-started SQP QPs (10 vs 42 on the hitch path).

``osqp.OSQP.setup`` only accepts SciPy CSC matrices; SciPy is a hard dependency of the
``osqp`` package itself and is used here solely to hand OSQP its sparsity pattern.
"""

from __future__ import annotations

import math

import numpy as np
import osqp
from osqp.interface import SolverStatus
from scipy import sparse  # required by osqp.OSQP.setup (osqp depends on scipy); no numerics here

from planner.ik_qp.backends.base import QP_INFINITY, QPData, QPResult, QPStatus
from planner.ik_qp.errors import IKInputError

__all__ = ["OSQPBackend", "OSQP_SETTINGS", "polish_solution"]

#: Settings applied to every OSQP problem (override through ``OSQPBackend(**settings)``).
OSQP_SETTINGS: dict = {
    "eps_abs": 1e-9,
    "eps_rel": 1e-9,
    "eps_prim_inf": 1e-6,  # infeasible linearisations go to the elastic QP; tighter is slow
    "eps_dual_inf": 1e-6,
    "alpha": 1.0,
    "rho": 0.1,
    "polishing": False,  # see the module docstring: polished in numpy instead
    "max_iter": 50,  # per round: then polish the iterate or continue (see OSQPBackend.solve)
    "check_termination": 5,
    "check_dualgap": False,
    "adaptive_rho": True,
    "adaptive_rho_interval": 25,  # fixed interval: deterministic (no timing-based adaptation)
    "scaled_termination": False,
    "warm_starting": True,
    "verbose": False,
}

_SOLVED = (SolverStatus.OSQP_SOLVED, SolverStatus.OSQP_SOLVED_INACCURATE)
_INFEASIBLE = (SolverStatus.OSQP_PRIMAL_INFEASIBLE, SolverStatus.OSQP_PRIMAL_INFEASIBLE_INACCURATE)


def _dense_csc(values: np.ndarray, upper_only: bool):
    """A CSC matrix holding *every* entry of ``values`` (explicit zeros kept, so the pattern
    never changes), or just its upper triangle. Returns ``(matrix, flat)`` where
    ``values.ravel(order="F")[flat]`` is the CSC data vector."""
    n_row, n_col = values.shape
    rows, indptr, flat = [], [0], []
    for j in range(n_col):
        col_rows = list(range(j + 1) if upper_only else range(n_row))
        rows += col_rows
        flat += [j * n_row + i for i in col_rows]
        indptr.append(len(rows))
    flat_a = np.array(flat, dtype=np.intp)
    data = values.ravel(order="F")[flat_a].astype(float)
    mat = sparse.csc_matrix(
        (data, np.array(rows, dtype=np.int64), np.array(indptr, dtype=np.int64)), shape=(n_row, n_col)
    )
    return mat, flat_a


def polish_solution(
    P: np.ndarray,
    c: np.ndarray,
    A: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    *,
    rounds: int = 4,
    tol: float = 1e-10,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Exact solution of ``min ½xᵀPx + cᵀx s.t. lb <= Ax <= ub`` on the active set suggested by
    an approximate primal-dual pair ``(x, y)`` (OSQP's rule: lower-active where
    ``Ax − lb < −y``, upper-active where ``ub − Ax < y``; equalities always active).

    Returns ``(x, y)`` verified to be primal feasible within ``tol · max(1, ‖(x, y)‖∞)`` with
    correctly signed multipliers, or ``None``. Violated rows are added and wrongly signed
    ones dropped for up to ``rounds`` re-solves of the (dense) KKT system.
    """
    n, m = P.shape[0], lb.size
    z = A @ x
    eq = lb == ub
    lower = z - lb < -y
    lower |= eq
    upper = ub - z < y
    upper &= ~lower
    ineq_lower = lower & ~eq
    for _ in range(rounds):
        idx = np.flatnonzero(lower | upper)
        na = idx.size
        K = np.zeros((n + na, n + na))
        K[:n, :n] = P
        Aa = A[idx]
        K[n:, :n] = Aa
        K[:n, n:] = Aa.T
        rhs = np.concatenate((-c, np.where(lower[idx], lb[idx], ub[idx])))
        try:
            sol = np.linalg.solve(K, rhs)
        except np.linalg.LinAlgError:  # degenerate (dependent) active rows
            sol = np.linalg.lstsq(K, rhs, rcond=None)[0]
        size = float(np.abs(sol).max())
        if not math.isfinite(size):
            return None
        xs = sol[:n]
        ys = np.zeros(m)
        ys[idx] = sol[n:]
        z = A @ xs
        t = tol * max(1.0, size)
        viol_lo = z < lb - t
        viol_up = z > ub + t
        wrong_lo = ineq_lower & (ys > t)
        wrong_up = upper & (ys < -t)
        bad = viol_lo | viol_up
        bad |= wrong_lo
        bad |= wrong_up
        if not bad.any():
            return xs, ys
        lower = (lower & ~wrong_lo) | viol_lo
        upper = ((upper & ~wrong_up) | viol_up) & ~lower
        ineq_lower = lower & ~eq
    return None


class _Persistent:
    """One set-up OSQP problem, the maps from dense buffers to its CSC data, and the
    update/solve calls (public ``osqp.OSQP`` methods, or the bound C solver, see below)."""

    def __init__(self, solver: osqp.OSQP, shape, p_flat, a_flat, raw_bindings: bool):
        self.solver, self.shape = solver, shape
        self.p_flat, self.a_flat = p_flat, a_flat
        self.l, self.u = np.zeros(shape[1]), np.zeros(shape[1])
        self.x0 = np.zeros(shape[0])
        self.solves = self.polished = 0
        self.last_status = ""
        # ``OSQP.update()``/``solve()`` spend ~15 µs per call in Python (importlib look-ups
        # of OSQP_INFTY, SciPy derivative caches, a SimpleNamespace of the info): on these
        # tiny QPs more than the solve itself. osqp 1.x keeps the C solver in ``_solver``
        # with the same update/solve methods; use it when present (bounds are clipped to
        # OSQP_INFTY here, as the wrapper does). ``raw_bindings=False`` forces the public API.
        raw = getattr(solver, "_solver", None) if raw_bindings else None
        needed = ("update_data_vec", "update_data_mat", "solve", "solution", "info")
        self.raw = raw if raw is not None and all(hasattr(raw, a) for a in needed) else None

    def update(
        self, c: np.ndarray, lb: np.ndarray, ub: np.ndarray, Px: np.ndarray | None, Ax: np.ndarray | None
    ) -> None:
        """New cost ``c`` and bounds ``lb``, ``ub``; new matrix values ``Px``, ``Ax`` unless None."""
        if self.raw is not None:
            self.raw.update_data_vec(c, lb, ub)
            if Px is not None:
                self.raw.update_data_mat(Px, None, Ax, None)
        elif Px is not None:
            self.solver.update(q=c, l=lb, u=ub, Px=Px, Ax=Ax)
        else:
            self.solver.update(q=c, l=lb, u=ub)

    def warm_start_zero_step(self) -> None:
        """Warm start from ``x = 0`` keeping the last multipliers: a new SQP iteration's step
        is unrelated to the last one (measured 8 vs 10 ADMM iterations on the hitch path),
        its active set and multipliers are not."""
        if self.raw is not None:
            self.raw.warm_start(self.x0, None)
        else:
            self.solver.warm_start(x=self.x0)

    def solve(self):
        """``(x, y, status value, status text)`` (fresh arrays)."""
        if self.raw is not None:
            self.raw.solve()
            info = self.raw.info
            return self.raw.solution.x, self.raw.solution.y, info.status_val, info.status
        res = self.solver.solve(raise_error=False)
        return np.array(res.x), np.array(res.y), res.info.status_val, res.info.status


class OSQPBackend:
    """OSQP with one persistent solver per ``key`` (re-``setup`` only if the shape changes).

    Args:
        raw_bindings: Call the bound C solver directly (see :class:`_Persistent`); ``False``
            uses only the public ``osqp.OSQP`` methods (~30 µs slower per SQP iteration).
        **settings: OSQP settings overriding :data:`OSQP_SETTINGS`.
    """

    name = "osqp"

    def __init__(self, raw_bindings: bool = True, max_rounds: int = 20, **settings):
        allowed = set(OSQP_SETTINGS) | {"sigma", "scaling", "time_limit", "polish_refine_iter", "delta"}
        unknown = set(settings) - allowed
        if unknown:
            raise IKInputError(f"osqp settings: unknown {sorted(unknown)}; allowed: {sorted(allowed)}")
        self.settings = {**OSQP_SETTINGS, **settings}
        self.raw_bindings = bool(raw_bindings)
        if isinstance(max_rounds, bool) or not isinstance(max_rounds, int) or max_rounds < 1:
            raise IKInputError(f"max_rounds: must be an integer >= 1, got {max_rounds!r}")
        self.max_rounds = max_rounds
        self.setups = 0
        self._problems: dict[str, _Persistent] = {}

    def problem(self, key: str) -> _Persistent | None:
        """The persistent OSQP problem of ``key`` (for inspection), or ``None``."""
        return self._problems.get(key)

    def _setup(self, qp: QPData, key: str) -> _Persistent:
        P, p_flat = _dense_csc(qp.P, upper_only=True)
        A, a_flat = _dense_csc(qp.A, upper_only=False)
        solver = osqp.OSQP()
        lb, ub = np.maximum(qp.l, -QP_INFINITY), np.minimum(qp.u, QP_INFINITY)
        solver.setup(P=P, q=qp.c.copy(), A=A, l=lb, u=ub, **self.settings)
        entry = _Persistent(solver, qp.shape, p_flat, a_flat, self.raw_bindings)
        self.setups += 1
        self._problems[key] = entry
        return entry

    def solve(self, qp: QPData, key: str, matrices_changed: bool = True) -> QPResult:
        """Solve ``qp`` with the persistent problem ``key`` (set up on first use)."""
        entry = self._problems.get(key)
        if entry is None or entry.shape != qp.shape:
            entry = self._setup(qp, key)
        else:
            np.maximum(qp.l, -QP_INFINITY, out=entry.l)  # as OSQP.update() does
            np.minimum(qp.u, QP_INFINITY, out=entry.u)
            if matrices_changed:
                entry.update(qp.c, entry.l, entry.u, qp.P_flat_f[entry.p_flat], qp.A_flat_f[entry.a_flat])
                entry.warm_start_zero_step()
            else:  # same matrices (e.g. a second-order correction): warm start from the last solution
                entry.update(qp.c, entry.l, entry.u, None, None)
        x = y = None
        for round_ in range(1, self.max_rounds + 1):
            x, y, status, text = entry.solve()
            entry.solves += 1
            if not math.isfinite(float(x @ x) + float(y @ y)):
                break
            if status in _SOLVED:
                # Polish when a non-equality row carries a multiplier; otherwise the ADMM
                # point is accurate to eps relative to the (scaled) step.
                if (np.abs(y) * (qp.l != qp.u)).max() > 1e-12 * (1.0 + float(np.abs(y).max())):
                    polished = polish_solution(qp.P, qp.c, qp.A, qp.l, qp.u, x, y)
                    if polished is not None:
                        entry.polished += 1
                        entry.last_status = "solved"
                        return QPResult(polished[0], polished[1], "solved", "polished")
                entry.last_status = "solved"
                return QPResult(x, y, "solved", text)
            if status != SolverStatus.OSQP_MAX_ITER_REACHED:
                break
            # ADMM's tail is slow on degenerate active sets, but its iterate usually names
            # the active set already: polish it (after rounds 1, 2, 4, 8, ...); else
            # continue ADMM from where it stopped.
            if round_ & (round_ - 1):
                continue
            polished = polish_solution(qp.P, qp.c, qp.A, qp.l, qp.u, x, y)
            if polished is not None:
                entry.polished += 1
                entry.last_status = "solved"
                return QPResult(polished[0], polished[1], "solved", "polished ADMM iterate")
        outcome: QPStatus = "infeasible" if status in _INFEASIBLE else "failed"
        entry.last_status = outcome
        # Do not warm-start the next solve from a diverged iterate.
        entry.solver.warm_start(x=np.zeros(qp.n_var), y=np.zeros(qp.n_row))
        return QPResult(np.zeros(qp.n_var), np.zeros(qp.n_row), outcome, text)
