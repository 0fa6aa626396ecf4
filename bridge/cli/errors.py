"""The command line's own error: bad arguments or a missing input file."""

from __future__ import annotations

from planner.errors import HitchInputError

__all__ = ["CLIError"]


class CLIError(HitchInputError):
    """A user-facing error of the command line: printed as one line, exit status 2."""
