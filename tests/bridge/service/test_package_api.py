"""The service's and the terminal's package facades and error classes: every public name of a
package resolves to the object of its defining module, and every error class the service and the
web terminal define derives from the project's root (input errors also from ``ValueError``)."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

import bridge.service
import bridge.web
from bridge.link.can_link import CanLink
from bridge.service.motion.link_port import LinkPort
from planner.errors import HitchError, HitchInputError

FACADES = ("bridge.service", "bridge.service.motion", "bridge.service.maneuvers", "bridge.web")


def _modules() -> list[str]:
    out = []
    for pkg in (bridge.service, bridge.web):
        for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
            out.append(info.name)
    return sorted(out)


@pytest.mark.parametrize("name", FACADES)
def test_every_public_name_of_a_facade_is_its_defining_modules(name):
    pkg = importlib.import_module(name)
    assert pkg.__all__ and len(set(pkg.__all__)) == len(pkg.__all__)
    for public in pkg.__all__:
        value = getattr(pkg, public)
        source = importlib.import_module(pkg._SOURCES[public])
        assert getattr(source, public) is value, public
        assert public in source.__all__, f"{public} is not in {source.__name__}.__all__"
    assert not hasattr(pkg, "nothing_here")  # an unknown name is an AttributeError, not a lazy import


def test_every_error_class_derives_from_the_project_root():
    errors = []
    for mod_name in _modules():
        mod = importlib.import_module(mod_name)
        for _, cls in inspect.getmembers(mod, inspect.isclass):
            if issubclass(cls, BaseException) and cls.__module__ == mod_name:
                errors.append(cls)
    assert len(errors) >= 20, [e.__name__ for e in errors]
    not_rooted = [e.__qualname__ for e in errors if not issubclass(e, HitchError)]
    assert not not_rooted
    input_not_input = [
        e.__qualname__ for e in errors if issubclass(e, ValueError) and not issubclass(e, HitchInputError)
    ]
    assert not input_not_input


def test_the_can_link_offers_what_the_motion_controller_uses():
    """Structural: every member of :class:`LinkPort` exists on :class:`CanLink` (mypy checks the types)."""
    members = [n for n in vars(LinkPort) if not n.startswith("_")]
    assert set(members) == {
        "config",
        "status",
        "latest_state",
        "check_reference",
        "send_reference",
        "stop_motion",
        "clear_faults",
    }
    for n in members:
        assert hasattr(CanLink, n), n
