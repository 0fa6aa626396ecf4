"""Shared fixtures: models are built once per session (CasADi graph construction ~0.3 s)."""

import numpy as np
import pytest

from planner.model.kinematics import HitchModel


@pytest.fixture(scope="session")
def model() -> HitchModel:
    return HitchModel.from_profile("thesis-t132", "2")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261123)
