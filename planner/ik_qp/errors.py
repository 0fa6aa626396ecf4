"""The error of the IK layer: a malformed request (target, weights, seed, mechanism, problem,
solver settings, QP backend)."""

from __future__ import annotations

from planner.errors import HitchInputError

__all__ = ["IKInputError"]


class IKInputError(HitchInputError):
    """A malformed argument to the IK layer; the message names the field and what is allowed.

    An out-of-reach target is no error: the solvers return status ``"limited"`` or ``"failed"``.
    """
