"""A Denavit–Hartenberg arm as a :class:`~planner.ik_qp.mechanism.Mechanism` of the SQP core.

Task: the tool pose as t(q) = [p (3); vec(R) (9)] — position [m] and the rotation matrix.
Its error target − t weights the position and the chordal distance ‖R_target − R‖_F, a
metric on SO(3) that is zero exactly when the rotations agree (no Euler angles, no
singularities of a parametrisation). Bounds: the joint limits, reported as
``joint:<joint>:min|max`` (not the hitch's ``stroke:…``).

A serial arm has up to eight inverse-kinematics solutions per pose (more with joint ranges
beyond ±π), so the local SQP solver can stop in a local minimum of the pose error at a joint
limit although the target is reachable: a ``"limited"`` result then says "a local minimum or
out of reach" rather than claiming the target is out of reach. The closed form
:func:`planner.arm.analytic.solve_arm_ik` lists every solution of a spherical-wrist arm.
"""

from __future__ import annotations

import math

import numpy as np

from planner.arm.dh import DHChain, build_casadi_chain
from planner.arm.transforms import ArmInputError
from planner.errors import unit_hint
from planner.ik_qp.mechanism import Mechanism

__all__ = ["build_arm_mechanism", "arm_target", "arm_weights"]

#: Accepted ``orientation_length`` of :func:`arm_weights` [m].
_MAX_ORIENTATION_LENGTH = 100.0


#: appended to the reason of a local minimum (Mechanism.several_solutions_note)
SEVERAL_SOLUTIONS_NOTE = "for the arm the closed form solve_arm_ik lists every solution"


def build_arm_mechanism(chain: DHChain) -> Mechanism:
    """The chain as a :class:`~planner.ik_qp.mechanism.Mechanism` whose limits are joint limits
    (``joint:<joint>:min|max``) and which has several IK solutions per pose: task ``[p; vec(R)]``
    (12 rows: position [m], the rotation matrix column-wise), bounds the joint limits [rad or m]."""
    cc = build_casadi_chain(chain)
    names = tuple(link.name or f"q{i + 1}" for i, link in enumerate(chain.links))
    return Mechanism(
        name="arm",
        actuator_names=names,
        lower=np.array([link.lower for link in chain.links]),
        upper=np.array([link.upper for link in chain.links]),
        task=cc.pose,
        task_names=("px", "py", "pz") + tuple(f"r{i}{j}" for j in range(1, 4) for i in range(1, 4)),
        limit_kind="joint",
        several_solutions=True,
        several_solutions_note=SEVERAL_SOLUTIONS_NOTE,
    )


def arm_target(position, rotation) -> np.ndarray:
    """Task vector of a target pose: position (3,) [m] and the rotation matrix (3x3, or its 9 entries
    row by row) stacked column-wise.

    Raises :class:`~planner.arm.transforms.ArmInputError` naming the argument when ``position`` is
    not 3 finite numbers or ``rotation`` not 9 finite numbers; the rotation is not checked for
    orthonormality (the chordal error accepts any matrix)."""
    p = _finite_array(position, 3, "position", "3 numbers [m] (x, y, z)")
    R = _finite_array(rotation, 9, "rotation", "a 3x3 matrix (9 numbers)").reshape(3, 3)
    return np.concatenate([p, R.reshape(9, order="F")])


def _finite_array(value, size: int, field_name: str, expected: str) -> np.ndarray:
    """``value`` as a flat float array of ``size`` finite values, or :class:`ArmInputError`."""
    if isinstance(value, (str, bytes)):
        raise ArmInputError(f"{field_name} must be {expected}, got text {value!r}")
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ArmInputError(f"{field_name} must be {expected}, got {value!r}") from None
    if arr.size != size:
        raise ArmInputError(f"{field_name} must be {expected}, got shape {arr.shape}")
    arr = arr.reshape(-1)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise ArmInputError(f"{field_name}[{int(bad[0])}] must be finite, got {arr[int(bad[0])]}")
    return arr


def arm_weights(orientation_length: float = 0.1) -> np.ndarray:
    """Task weights: 1 per metre of position; ``orientation_length`` [m] per unit of chordal rotation
    error, ``0 <= orientation_length <= 100`` m (0: position only)."""
    v = orientation_length
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise ArmInputError(f"orientation_length must be a number [m], got {type(v).__name__} {v!r}")
    v = float(v)
    if not (math.isfinite(v) and 0.0 <= v <= _MAX_ORIENTATION_LENGTH):
        raise ArmInputError(
            f"orientation_length = {v} m is outside the allowed [0, {_MAX_ORIENTATION_LENGTH:g}] m"
            + unit_hint(v, 0.0, _MAX_ORIENTATION_LENGTH, "m")
        )
    return np.r_[np.ones(3), np.full(9, v)]
