"""Helpers shared by tests (import as ``from tests.helpers import …``)."""

from __future__ import annotations

import importlib
import subprocess
import sys
from types import ModuleType

import numpy as np
import pytest

from planner.errors import HitchInputError
from planner.model.kinematics import HitchModel
from planner.model.types import KinematicsError

__all__ = ["bridge_modules_after", "check_facade_errors", "check_facade_names", "random_closing_actuators"]


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


def check_facade_names(package: ModuleType) -> None:
    """Every public name of a lazy package facade is listed once and is its defining module's object."""
    sources = package._SOURCES
    assert len(set(package.__all__)) == len(package.__all__) == len(sources)
    for name in package.__all__:
        module = importlib.import_module(sources[name])
        assert name in module.__all__, (name, module.__name__)
        assert getattr(package, name) is getattr(module, name), name
    assert set(dir(package)) >= set(package.__all__)
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        package.nothing_here  # noqa: B018


def check_facade_errors(package: ModuleType) -> None:
    """Every public exception of a package is a HitchInputError (there is at least one)."""
    errors = [
        n
        for n in package.__all__
        if isinstance(getattr(package, n), type) and issubclass(getattr(package, n), Exception)
    ]
    assert errors
    for name in errors:
        assert issubclass(getattr(package, name), HitchInputError), name


def bridge_modules_after(statement: str) -> set[str]:
    """The ``bridge`` modules a fresh interpreter has loaded after ``statement``."""
    code = f"import sys; {statement}; print(' '.join(m for m in sys.modules if m.startswith('bridge')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    return set(out.split())
