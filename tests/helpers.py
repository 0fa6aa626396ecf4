"""Helpers shared by tests (import as ``from tests.helpers import …``)."""

from __future__ import annotations

import numpy as np

from planner.model.kinematics import HitchModel
from planner.model.types import KinematicsError

__all__ = ["random_closing_actuators"]


def random_closing_actuators(model: HitchModel, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Random actuator vectors uniformly inside the strokes for which the mechanism closes."""
    out = []
    while len(out) < n:
        q = model.lower + (model.upper - model.lower) * rng.random(5)
        try:
            model.forward(q)
        except KinematicsError:
            continue
        out.append(q)
    return out
