"""The hitch as a :class:`~planner.ik_qp.mechanism.Mechanism` of the SQP core.

Actuators q = (lift, tilt, top, left, right). Task: the controlled pose (x, z, roll,
pitch). Equality: implement rigidity |L − R| − span = 0 (thesis 2.49). Inequalities:
top-link yaw and pitch relative to the mount reference (thesis §3.2) and the lower-link
ends' heights above the ground (profile ground clearance). Bounds: the strokes.
All functions share the model's exact CasADi graph and its implicit-function Jacobian.
"""

from __future__ import annotations

import casadi as ca

from planner.ik_qp.mechanism import Mechanism
from planner.model.hard_limits import FEATURE_LIMIT_ROWS, HardLimits
from planner.model.kinematics import FEATURE_NAMES, HitchModel
from planner.model.limit_names import LimitName
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES

__all__ = ["build_hitch_mechanism", "TASK_ROWS"]

#: Feature rows of the task (x, z, roll, pitch).
TASK_ROWS = tuple(FEATURE_NAMES.index(n) for n in CONTROLLED_POSE_NAMES)


def build_hitch_mechanism(model: HitchModel, limits: HardLimits | None = None) -> Mechanism:
    """The hitch of ``model`` as a mechanism, with the hard limits ``limits`` (default: the model's)."""
    limits = limits or HardLimits.from_model(model)
    sym = model.symbolic
    q, f, jac = sym.q, sym.features, sym.jacobian
    span_row = FEATURE_NAMES.index("lower_span")
    ineq_rows = list(limits.feature_index)

    def fn(label: str, rows: list[int], offset: float = 0.0) -> ca.Function:
        return ca.Function(f"hitch_{label}", [q], [f[rows] - offset, jac[rows, :]])

    return Mechanism(
        name="hitch",
        actuator_names=ACTUATOR_NAMES,
        lower=limits.actuator_lower,
        upper=limits.actuator_upper,
        task=fn("task", list(TASK_ROWS)),
        task_names=CONTROLLED_POSE_NAMES,
        equality=fn("rigidity", [span_row], model.span),
        equality_names=("implement_rigidity",),
        inequality=fn("limits", ineq_rows),
        inequality_names=tuple(r[0] for r in FEATURE_LIMIT_ROWS),
        g_lower=limits.feature_lower,
        g_upper=limits.feature_upper,
        # the clearance rows have no upper bound; their never-reached max sides are named z_<side>_end_max
        inequality_side_names=tuple(
            (r[1], r[2] or str(LimitName(r[0], side="max", flat=True))) for r in FEATURE_LIMIT_ROWS
        ),
    )
