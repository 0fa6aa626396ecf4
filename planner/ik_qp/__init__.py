"""Inverse kinematics as a constrained QP: the mechanism-agnostic SQP core and the hitch IK; the thesis's
geometric, DLS and hybrid IK kept as measured baselines (:mod:`planner.ik_qp.baselines`)."""

from planner.ik_qp.baselines import DLSIK, GeometricIK, HybridIK
from planner.ik_qp.errors import IKInputError
from planner.ik_qp.hitch_ik import BACKENDS, IKSolver, default_weights
from planner.ik_qp.mechanism import Mechanism, build_mechanism
from planner.ik_qp.problem import IKProblem, IKSolution, TaskBounds, build_ik_problem
from planner.ik_qp.result import IKResult, Target
from planner.ik_qp.sqp import SQPSettings, SQPSolver

__all__ = [
    "BACKENDS",
    "DLSIK",
    "GeometricIK",
    "HybridIK",
    "IKInputError",
    "IKSolver",
    "default_weights",
    "Mechanism",
    "build_mechanism",
    "IKProblem",
    "IKSolution",
    "TaskBounds",
    "build_ik_problem",
    "IKResult",
    "Target",
    "SQPSettings",
    "SQPSolver",
]
