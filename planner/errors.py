"""The one root of every hitch-planner error.

Catch :class:`HitchError` to handle any error the project raises on purpose; anything
else is a bug. Errors caused by bad input derive from :class:`ValueError` as well
(:class:`HitchInputError`), so ``except ValueError`` keeps working for callers that
validate input.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

__all__ = ["HitchError", "HitchInputError", "distinct_texts", "first_line", "unit_hint", "unit_hint_within"]


class HitchError(Exception):
    """Root of every error the hitch planner, the bridge and the service raise on purpose."""


class HitchInputError(HitchError, ValueError):
    """Bad input: the message names the field, the value and what is allowed."""


def distinct_texts(value: float, bound: float) -> tuple[str, str]:
    """``value`` (6 significant digits) and ``bound`` (4) as a refusal prints them, with as many more digits as it
    takes for two different numbers to read differently: "pitch = 0.062 rad is above the workspace (… to 0.062
    rad)" read as a contradiction (the bound was 0.061999, or the value 2e-9 over it: a trial and a review)."""
    for extra in range(0, 12):
        shown, limit = f"{value:.{6 + extra}g}", f"{bound:.{4 + extra}g}"
        if shown != limit or value == bound:
            return shown, limit
    return repr(value), repr(bound)


def unit_hint(value: float, lo: float, hi: float, unit: str) -> str:
    """``; did you mean mm? …`` for a length [m], ``; did you mean degrees? …`` and/or ``mrad? …`` for an
    angle [rad], whose value read so lies in ``[lo, hi]``; ``""`` when none fits (a suffix for a
    :class:`HitchInputError` message about ``value`` outside ``[lo, hi]``). Angles are offered in mrad too:
    this product prints them so (a pose of ``plan-poses`` copied as radians read "did you mean degrees?").
    A mass [kg] is offered in tonnes (``; did you mean t? 1.2 t = 1200 kg``): a tractor's, an implement's or a
    ballast's mass typed in tonnes is a slip as likely as a length in mm."""
    if unit == "kg":
        kg = value * 1000.0
        return f"; did you mean t? {value:.6g} t = {kg:.6g} kg" if 0.0 < value and lo <= kg <= hi else ""
    if abs(value) < 1.0:
        return ""
    if unit == "m" and lo <= value / 1000.0 <= hi:
        return f"; did you mean mm? {value:.6g} mm = {value / 1000.0:.6g} m"
    if unit != "rad":
        return ""
    hints = []
    if lo <= math.radians(value) <= hi:
        hints.append(f"degrees? {value:.6g} deg = {math.radians(value):.6g} rad")
    if lo <= value / 1000.0 <= hi:
        hints.append(f"mrad? {value:.6g} mrad = {value / 1000.0:.6g} rad")
    return "; did you mean " + "; or ".join(hints) if hints else ""


def unit_hint_within(value: float, constraints: Iterable[object], unit: str) -> str:
    """:func:`unit_hint` for ``value`` against the bounds of ``constraints`` (objects with ``gt``/``ge``/``lt``/``le``
    attributes, as a pydantic field's metadata); open ends are infinite."""
    items = list(constraints)

    def bounds(names: tuple[str, str]) -> list[float]:
        return [float(getattr(c, a)) for c in items for a in names if getattr(c, a, None) is not None]

    return unit_hint(
        value, max(bounds(("gt", "ge")), default=-math.inf), min(bounds(("lt", "le")), default=math.inf), unit
    )


def first_line(exc: BaseException) -> str:
    """``Type: the first line of its text`` (third-party errors dump pages after it: Ruckig's input, a parser's
    state) for a message that names what went wrong."""
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text.splitlines()[0] if text else 'no message'}"
