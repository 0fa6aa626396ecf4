"""A Denavit–Hartenberg arm as a :class:`~planner.ik_qp.mechanism.Mechanism` of the SQP core.

Task: the tool pose as t(q) = [p (3); vec(R) (9)] — position [m] and the rotation matrix.
Its error target − t weights the position and the chordal distance ‖R_target − R‖_F, a
metric on SO(3) that is zero exactly when the rotations agree (no Euler angles, no
singularities of a parametrisation). Bounds: the joint limits.
"""

from __future__ import annotations

import numpy as np

from planner.arm.dh import DHChain, build_casadi_chain
from planner.ik_qp.mechanism import Mechanism

__all__ = ["build_arm_mechanism", "arm_target", "arm_weights"]


def build_arm_mechanism(chain: DHChain) -> Mechanism:
    cc = build_casadi_chain(chain)
    names = tuple(link.name or f"q{i + 1}" for i, link in enumerate(chain.links))
    return Mechanism(
        name="arm",
        actuator_names=names,
        lower=np.array([link.lower for link in chain.links]),
        upper=np.array([link.upper for link in chain.links]),
        task=cc.pose,
        task_names=("px", "py", "pz") + tuple(f"r{i}{j}" for j in range(1, 4) for i in range(1, 4)),
    )


def arm_target(position, rotation) -> np.ndarray:
    """Task vector of a target pose: position [m] and the rotation matrix stacked column-wise."""
    R = np.asarray(rotation, float).reshape(3, 3)
    return np.concatenate([np.asarray(position, float).reshape(3), R.reshape(9, order="F")])


def arm_weights(orientation_length: float = 0.1) -> np.ndarray:
    """1 per metre of position; ``orientation_length`` [m] per unit of chordal rotation error."""
    return np.r_[np.ones(3), np.full(9, orientation_length)]
