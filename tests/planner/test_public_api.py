"""The ``planner`` facades: every public name resolves to its defining module's object, names load
lazily, and every exception class the planner defines derives from ``HitchError``.

Truth: the modules themselves (walked with pkgutil), their ``__all__``, the facades' source text
(the ``TYPE_CHECKING`` imports) and ``sys.modules`` of a fresh interpreter.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import planner
from planner.errors import HitchError, HitchInputError

FACADES = ("planner", "planner.model", "planner.profiles", "planner.ik_qp", "planner.trajectory", "planner.limits")
LAZY_FACADES = ("planner", "planner.model", "planner.profiles", "planner.limits", "planner.arm")


def _all_modules() -> list[str]:
    names = ["planner"]
    names += [m.name for m in pkgutil.walk_packages(planner.__path__, prefix="planner.")]
    return sorted(names)


def _public_names() -> list[tuple[str, str]]:
    return [(pkg, name) for pkg in (*FACADES, "planner.arm") for name in importlib.import_module(pkg).__all__]


@pytest.mark.parametrize(("package", "name"), _public_names())
def test_every_public_name_resolves(package, name):
    module = importlib.import_module(package)
    value = getattr(module, name)
    assert value is not None
    assert name in dir(module)


@pytest.mark.parametrize("package", LAZY_FACADES)
def test_a_lazy_facade_lists_each_name_once_with_its_defining_module(package):
    module = importlib.import_module(package)
    sources = module._SOURCES
    assert len(set(module.__all__)) == len(module.__all__)
    assert set(module.__all__) == set(sources)
    for name, source in sources.items():
        defining = importlib.import_module(source)
        assert name in defining.__all__, (name, source)
        assert getattr(module, name) is getattr(defining, name), name


@pytest.mark.parametrize("package", LAZY_FACADES)
def test_the_type_checking_imports_match_the_sources(package):
    """What type checkers see (the ``if TYPE_CHECKING:`` imports) is what the facade loads."""
    path = Path(importlib.import_module(package).__file__)
    tree = ast.parse(path.read_text(encoding="utf-8"))
    seen: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for stmt in node.body:
                if isinstance(stmt, ast.ImportFrom):
                    seen.update({a.name: stmt.module for a in stmt.names})
    assert seen == importlib.import_module(package)._SOURCES


@pytest.mark.parametrize("package", LAZY_FACADES)
def test_an_unknown_name_is_an_attribute_error(package):
    module = importlib.import_module(package)
    with pytest.raises(AttributeError, match="has no attribute 'nothing_here'"):
        module.nothing_here  # noqa: B018


def test_the_version_is_a_string():
    assert isinstance(planner.__version__, str) and planner.__version__


def test_what_a_move_needs_is_in_the_top_level_facade():
    wanted = {
        "HitchModel",
        "Actuators",
        "Pose",
        "HitchState",
        "ACTUATOR_NAMES",
        "POSE_NAMES",
        "CONTROLLED_POSE_NAMES",
        "Profile",
        "load_profile",
        "IKSolver",
        "Target",
        "IKResult",
        "TrajectoryPlanner",
        "Plan",
        "MotionState",
        "Waypoint",
        "PlanError",
        "Guard",
        "GuardDecision",
        "GuardRefusal",
        "HitchError",
        "HitchInputError",
        "KinematicsError",
        "ProfileError",
        "SensorScaling",
        "ExactInverse",
        "Reachability",
        "LimitName",
    }
    assert wanted <= set(planner.__all__)


def _exception_classes() -> list[type]:
    found: dict[str, type] = {}
    for name in _all_modules():
        module = importlib.import_module(name)
        for _, obj in inspect.getmembers(module, inspect.isclass):
            if issubclass(obj, BaseException) and obj.__module__.startswith("planner"):
                found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return [found[k] for k in sorted(found)]


def test_the_module_walk_sees_the_errors():
    names = {c.__name__ for c in _exception_classes()}
    assert {"KinematicsError", "PlanError", "GuardRefusal", "IKInputError", "ArmProfileError"} <= names
    assert len(names) >= 20


@pytest.mark.parametrize("error", _exception_classes(), ids=lambda c: c.__name__)
def test_every_planner_exception_derives_from_hitch_error(error):
    assert issubclass(error, HitchError)
    if issubclass(error, ValueError):
        assert issubclass(error, HitchInputError), "input errors derive from HitchInputError"


def test_the_errors_keep_their_builtin_bases():
    """Callers that catch ValueError (the service maps it to "bad_request") or RuntimeError keep working."""
    from planner.ik_qp.errors import IKInputError
    from planner.trajectory.jog import JogError
    from planner.trajectory.plan import PlanError, TrajectoryInputError

    assert issubclass(IKInputError, ValueError) and issubclass(TrajectoryInputError, ValueError)
    assert issubclass(JogError, RuntimeError)
    assert not issubclass(TrajectoryInputError, PlanError)  # a malformed request is no "unreachable" plan


def _loaded_after(statement: str) -> set[str]:
    code = f"import sys\n{statement}\nprint('\\n'.join(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    return set(out.stdout.split())


@pytest.mark.parametrize(
    "statement",
    ["import planner", "import planner.errors", "import planner.model.types", "from planner.model import Actuators"],
)
def test_light_imports_load_no_casadi_or_ruckig(statement):
    loaded = _loaded_after(statement)
    assert "casadi" not in loaded and "ruckig" not in loaded, statement


def test_a_name_loads_its_module_on_first_use():
    loaded = _loaded_after("import planner\nplanner.HitchModel")
    assert "planner.model.kinematics" in loaded and "casadi" in loaded
    assert not any(m.startswith("planner.limits") for m in loaded)
