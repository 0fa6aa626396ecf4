"""The ``bridge.sim`` package (the simulated cylinder ECU): its public names, their error root, lazy loading."""

import importlib
import subprocess
import sys

import pytest

import bridge.sim as package
from planner.errors import HitchInputError


def test_every_public_name_is_the_object_of_its_defining_module():
    assert len(set(package.__all__)) == len(package.__all__) == len(package._SOURCES)
    for name in package.__all__:
        module = importlib.import_module(package._SOURCES[name])
        assert name in module.__all__, (name, module.__name__)
        assert getattr(package, name) is getattr(module, name), name
    assert set(dir(package)) >= set(package.__all__)
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        package.nothing_here  # noqa: B018


def test_every_public_error_is_a_hitch_input_error():
    errors = [
        n
        for n in package.__all__
        if isinstance(getattr(package, n), type) and issubclass(getattr(package, n), Exception)
    ]
    assert errors
    for name in errors:
        assert issubclass(getattr(package, name), HitchInputError), name


def _bridge_modules_after(statement: str) -> set[str]:
    code = f"import sys; {statement}; print(' '.join(m for m in sys.modules if m.startswith('bridge')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    return set(out.split())


def test_the_package_loads_nothing_and_the_ecu_model_needs_no_link():
    assert _bridge_modules_after("import bridge.sim") == {"bridge", "bridge.sim"}
    loaded = _bridge_modules_after("import bridge.sim.ecu")
    assert "bridge.sim.ecu" in loaded
    assert not any(m.startswith("bridge.link") for m in loaded), loaded
