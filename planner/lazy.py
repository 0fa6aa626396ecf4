"""Lazy public names of the package facades (PEP 562), for planner's and bridge's ``__init__`` files.

A facade ``__init__`` lists its public names with their defining modules and gets module-level
``__getattr__`` / ``__dir__`` from :func:`lazy_exports`: a name is imported from its defining
module on first use and cached in the package, so ``import planner.errors`` or
``import planner.model.types`` loads nothing else (no CasADi, no Ruckig). The facade imports the
same names under ``TYPE_CHECKING`` for type checkers.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(
    package: str, namespace: dict[str, Any], sources: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for the package ``package`` whose globals are ``namespace``;
    ``sources`` maps each public name to the module that defines it."""

    def __getattr__(name: str) -> Any:
        module = sources.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(sources))

    return __getattr__, __dir__
