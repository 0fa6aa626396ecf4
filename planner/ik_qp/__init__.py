"""Inverse kinematics as a constrained QP (issue 3): the mechanism-agnostic SQP core and the hitch IK."""

from .hitch_ik import BACKENDS, IKSolver, default_weights
from .mechanism import Mechanism, build_mechanism
from .problem import IKProblem, IKSolution, TaskBounds, build_ik_problem
from .result import IKResult, Target
from .sqp import SQPSettings, SQPSolver

__all__ = [
    "BACKENDS", "IKSolver", "default_weights", "Mechanism", "build_mechanism", "IKProblem", "IKSolution",
    "TaskBounds", "build_ik_problem", "IKResult", "Target", "SQPSettings", "SQPSolver",
]
