"""The one root of every hitch-planner error.

Catch :class:`HitchError` to handle any error the project raises on purpose; anything
else is a bug. Errors caused by bad input derive from :class:`ValueError` as well
(:class:`HitchInputError`), so ``except ValueError`` keeps working for callers that
validate input.
"""

from __future__ import annotations

__all__ = ["HitchError", "HitchInputError"]


class HitchError(Exception):
    """Root of every error the hitch planner, the bridge and the service raise on purpose."""


class HitchInputError(HitchError, ValueError):
    """Bad input: the message names the field, the value and what is allowed."""
