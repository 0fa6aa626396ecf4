"""Shared fixtures: models are built once per session (CasADi graph construction ~0.3 s).

After collection, everything imported and collected so far is frozen out of the garbage collector
(``gc.freeze``, as ``hitch serve`` does with its start-up objects): services with
``control_core = "thread"`` run in this process, and a full collection over the ~145 000 objects of
the collected suite pauses every thread of it, their control and CAN threads included (up to
~270 ms measured over a suite run)."""

import gc

import numpy as np
import pytest

from planner.model.kinematics import HitchModel


@pytest.fixture(scope="session")
def model() -> HitchModel:
    return HitchModel.from_profile("thesis-t132", "2")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261123)


def pytest_collection_finish(session: pytest.Session) -> None:
    gc.collect()
    gc.freeze()
