"""QP backends of the SQP core: one problem form, one result type, several solvers.

The form and types are in :mod:`planner.ik_qp.backends.base` (OSQP form, OSQP multiplier
signs). Backends: ``"osqp"`` (default; one persistent ``osqp.OSQP`` per problem key and shape,
``update()``-d and warm-started) and, through qpsolvers, ``"daqp"``, ``"quadprog"``,
``"proxqp"`` and ``"clarabel"``; each is imported when first asked for.
"""

from __future__ import annotations

from typing import Any

from planner.ik_qp.backends.base import BACKENDS, QP_INFINITY, QPBackend, QPData, QPResult, QPStatus
from planner.ik_qp.errors import IKInputError

__all__ = [
    "BACKENDS",
    "QP_INFINITY",
    "QPData",
    "QPResult",
    "QPBackend",
    "QPStatus",
    "make_backend",
]


def make_backend(name: str, **options: Any) -> QPBackend:
    """Create the backend ``name`` (one of :data:`BACKENDS`); ``options`` go to the solver."""
    if name == "osqp":
        from planner.ik_qp.backends.osqp_backend import OSQPBackend

        return OSQPBackend(**options)
    if name in BACKENDS:
        from planner.ik_qp.backends.qpsolvers_backend import QpsolversBackend

        return QpsolversBackend(name, **options)
    raise IKInputError(f"backend: unknown QP backend {name!r}; allowed: {', '.join(BACKENDS)}")
