"""Shared fixtures: models are built once per session (CasADi graph construction ~0.3 s)."""

import numpy as np
import pytest

from planner.kinematics import HitchModel


@pytest.fixture(scope="session")
def model() -> HitchModel:
    return HitchModel.from_profile("thesis-t132", "2")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261123)


def random_closing_actuators(model, rng, n):
    """Random actuator vectors uniformly inside the strokes for which the mechanism closes."""
    from planner.types import KinematicsError

    out = []
    while len(out) < n:
        q = model.lower + (model.upper - model.lower) * rng.random(5)
        try:
            model.forward(q)
        except KinematicsError:
            continue
        out.append(q)
    return out
