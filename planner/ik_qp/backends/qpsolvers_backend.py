"""QP backends through qpsolvers: DAQP, quadprog, ProxQP and Clarabel.

The OSQP-form QP (``l <= A x <= u``, leading identity box rows) is converted to the
qpsolvers form (``G x <= h``, ``A_eq x = b``, ``lb <= x <= ub``) on every call (these
solvers are not persistent here); multipliers are mapped back to OSQP signs; bounds with
``|value| >= QP_INFINITY`` are dropped. Tolerances are explicit: ProxQP's defaults
(``eps_abs = 1e-3``) return inaccurate "solved" answers, so it runs with
``eps_abs = 1e-12``; Clarabel runs with 1e-10 gap/feasibility tolerances (tighter ones end
in ``InsufficientProgress`` on these small, well-scaled QPs; such an end is accepted when
the point is primal feasible). Known: ProxQP 0.8 reports "primal infeasible" for about
0.2 % of random feasible test QPs (cf. proxsuite issue #445); the SQP then restores
through its elastic QP or more damping.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import qpsolvers

from planner.ik_qp.backends.base import BACKENDS, QP_INFINITY, QPData, QPResult, QPStatus
from planner.ik_qp.errors import IKInputError

__all__ = ["QpsolversBackend", "QPSOLVERS_OPTIONS"]

#: Default solver options per backend (override through ``QpsolversBackend(name, **options)``).
QPSOLVERS_OPTIONS: dict[str, dict] = {
    "daqp": {},
    "quadprog": {},
    "proxqp": {"eps_abs": 1e-12, "eps_rel": 0.0, "max_iter": 10000, "backend": "dense"},
    "clarabel": {
        "tol_gap_abs": 1e-10,
        "tol_gap_rel": 1e-10,
        "tol_feas": 1e-10,
        "tol_ktratio": 1e-10,
        "max_iter": 200,
    },
}


class QpsolversBackend:
    """One qpsolvers solver (``"daqp"``, ``"quadprog"``, ``"proxqp"`` or ``"clarabel"``)."""

    def __init__(self, name: str, **options: Any):
        if name not in BACKENDS or name == "osqp":
            allowed = ", ".join(b for b in BACKENDS if b != "osqp")
            raise IKInputError(f"backend: {name!r} is not a qpsolvers backend here; allowed: {allowed}")
        if name not in qpsolvers.available_solvers:
            raise IKInputError(f"backend: {name!r} is not installed (available: {qpsolvers.available_solvers})")
        self.name = name
        self.options = {**QPSOLVERS_OPTIONS[name], **options}

    @staticmethod
    def _nearly_solved(sol: qpsolvers.Solution, qp: QPData) -> bool:
        """Clarabel stops with ``InsufficientProgress``/``AlmostSolved`` when the (scaled) QP
        is already solved to about its tolerance: accept a finite, primal-feasible point."""
        status = str(sol.extras.get("status", "")) if sol.extras else ""
        if not ("InsufficientProgress" in status or "AlmostSolved" in status):
            return False
        x = sol.x
        if x is None or not np.all(np.isfinite(x)) or sol.z is None:
            return False
        z = qp.A @ x
        tol = 1e-7 * max(1.0, float(np.abs(x).max()))
        return bool(np.all(z >= qp.l - tol) and np.all(z <= qp.u + tol))

    def solve(self, qp: QPData, key: str, matrices_changed: bool = True) -> QPResult:
        """Solve ``qp`` (``key`` and ``matrices_changed`` are irrelevant: nothing persists)."""
        nv = qp.n_var
        A, row_lb, row_ub = qp.A[nv:], qp.l[nv:], qp.u[nv:]
        lb, ub = qp.l[:nv], qp.u[:nv]
        eq = row_lb == row_ub
        up = ~eq & (np.abs(row_ub) < QP_INFINITY)
        lo = ~eq & (np.abs(row_lb) < QP_INFINITY)
        box = bool(np.all(np.abs(lb) < QP_INFINITY) and np.all(np.abs(ub) < QP_INFINITY))
        g_blocks, h_blocks = [A[up], -A[lo]], [row_ub[up], -row_lb[lo]]
        box_up, box_lo = np.abs(ub) < QP_INFINITY, np.abs(lb) < QP_INFINITY
        if not box:  # infinite box sides: finite ones become general rows
            eye = np.eye(nv)
            g_blocks += [eye[box_up], -eye[box_lo]]
            h_blocks += [ub[box_up], -lb[box_lo]]
        G = np.vstack(g_blocks)
        h = np.concatenate(h_blocks)
        problem = qpsolvers.Problem(
            qp.P,
            qp.c,
            G if G.shape[0] else None,
            h if G.shape[0] else None,
            A[eq] if eq.any() else None,
            row_ub[eq] if eq.any() else None,
            lb if box else None,
            ub if box else None,
        )
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                sol = qpsolvers.solve_problem(problem, solver=self.name, **self.options)
        except Exception as exc:  # solver-specific errors (e.g. quadprog "constraints are inconsistent")
            text = str(exc)
            status: QPStatus = "infeasible" if "inconsistent" in text or "infeasible" in text.lower() else "failed"
            return QPResult(np.zeros(nv), np.zeros(qp.n_row), status, f"{self.name}: {text}")
        if not sol.found and self._nearly_solved(sol, qp):
            sol.found = True
        if not sol.found or sol.x is None or not np.all(np.isfinite(sol.x)):
            detail = str(sol.extras.get("status", "")) if sol.extras else ""
            status = "infeasible" if "nfeasib" in detail else "failed"
            return QPResult(np.zeros(nv), np.zeros(qp.n_row), status, f"{self.name}: {detail or 'not solved'}")
        y = np.zeros(qp.n_row)
        yg = y[nv:]
        z = np.asarray(sol.z) if sol.z is not None else np.zeros(0)
        n_up, n_lo = int(up.sum()), int(lo.sum())
        yg[up] += z[:n_up]
        yg[lo] -= z[n_up : n_up + n_lo]
        if eq.any():
            yg[eq] = np.asarray(sol.y)
        if box:
            y[:nv] = np.asarray(sol.z_box) if sol.z_box is not None else 0.0
        else:
            k = n_up + n_lo
            nb_up = int(box_up.sum())
            y[:nv][box_up] += z[k : k + nb_up]
            y[:nv][box_lo] -= z[k + nb_up :]
        return QPResult(np.asarray(sol.x, dtype=float).copy(), y, "solved", self.name)
