"""The problem form, result type and solver protocol every QP backend shares.

Every QP is stated in OSQP form ``min ½ xᵀPx + cᵀx  s.t.  l <= A x <= u`` where the first
``n_var`` rows of ``A`` are the identity (box rows on the variables) and the remaining rows
are general constraints (``l == u`` marks an equality; ``|bound| >= QP_INFINITY`` is none).
Multipliers follow the OSQP sign convention: ``P x + c + Aᵀ y = 0``, ``y_i > 0`` when row
``i`` is at its upper side, ``y_i < 0`` at its lower side.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from planner.ik_qp.errors import IKInputError

__all__ = [
    "BACKENDS",
    "QP_INFINITY",
    "QPData",
    "QPResult",
    "QPBackend",
    "QPStatus",
]

#: Names accepted by :func:`make_backend`.
BACKENDS: tuple[str, ...] = ("osqp", "daqp", "quadprog", "proxqp", "clarabel")

QPStatus = Literal["solved", "infeasible", "failed"]

#: Bounds with ``|value| >= QP_INFINITY`` are infinite (OSQP's ``OSQP_INFTY``).
QP_INFINITY = 1e30


class QPData:
    """Pre-allocated buffers of one QP in OSQP form (mutable workspace, reused every iteration).

    Attributes:
        P: ``(n_var, n_var)`` symmetric positive semidefinite cost matrix.
        c: ``(n_var,)`` linear cost.
        A: ``(n_row, n_var)`` constraint matrix; ``A[:n_var]`` is the identity.
        P_flat_f, A_flat_f: Column-major flat views of ``P`` and ``A``.
        l, u: ``(n_row,)`` bounds (``±QP_INFINITY`` or beyond = none, ``l == u`` for equalities).
    """

    __slots__ = ("n_var", "n_row", "P", "c", "A", "l", "u", "P_flat_f", "A_flat_f")

    def __init__(self, n_var: int, n_row: int):
        if n_row < n_var:
            raise IKInputError(f"n_row ({n_row}) must include the {n_var} box rows")
        self.n_var, self.n_row = n_var, n_row
        # Column-major storage: the column-major flat views feed CSC data without copies.
        self.P = np.zeros((n_var, n_var), order="F")
        self.c = np.zeros(n_var)
        self.A = np.zeros((n_row, n_var), order="F")
        self.A[:n_var] = np.eye(n_var)
        self.l = np.zeros(n_row)
        self.u = np.zeros(n_row)
        self.P_flat_f = self.P.reshape(-1, order="F")
        self.A_flat_f = self.A.reshape(-1, order="F")

    @property
    def shape(self) -> tuple[int, int]:
        return self.n_var, self.n_row


@dataclass(frozen=True, slots=True)
class QPResult:
    """Solution of one QP: primal ``x`` (n_var,), multipliers ``y`` (n_row, OSQP signs)."""

    x: np.ndarray
    y: np.ndarray
    status: QPStatus
    detail: str = ""

    @property
    def solved(self) -> bool:
        return self.status == "solved"


class QPBackend(Protocol):
    """A QP solver. ``key`` names a persistent problem (e.g. ``"main"``, ``"elastic"``);
    ``matrices_changed=False`` promises ``P`` and ``A`` are unchanged since the last solve
    of that key (only ``c``, ``l``, ``u`` moved), which lets persistent solvers skip a
    refactorisation."""

    name: str

    def solve(self, qp: QPData, key: str, matrices_changed: bool = True) -> QPResult: ...
