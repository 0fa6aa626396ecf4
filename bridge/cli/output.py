"""Terminal output of the ``hitch`` commands: one console factory and markup escaping.

Text that comes from data (limit names such as ``workspace:x:max``, fault reasons, preset and
maneuver names, service messages) must print as it is: rich would read ``:x:`` as an emoji code
and ``[red]`` as markup. :func:`console` turns emoji codes off for every command; :func:`esc`
escapes markup in a data value that is embedded in a line with the command's own markup.
"""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.markup import escape

__all__ = ["console", "esc"]


def console(**kwargs: Any) -> Console:
    """A rich console that never turns ``:name:`` into an emoji (kwargs as for :class:`Console`)."""
    return Console(emoji=False, **kwargs)


def esc(value: object) -> str:
    """``str(value)`` with rich markup escaped, for data inside a marked-up line."""
    return escape(str(value))
