"""Unidirectional final approach: a goto ends rising in every DOF (backlash take-up).

Two things make where the implement stops depend on the side it came from:

* **pin play** at the lower-link balls and top-link pins: the implement lags the mechanism by up to
  the play band in each DOF (a dead band), on the side the motion came from;
* **the ECU's stop inside a count**: the unit controller cuts the valve when the AD reading reaches
  the reference count, so a piston that rose into its count stops near the count's lower edge
  (plus what it coasts), one that fell into it near the upper edge.

Approached from the same side every time, both become fixed offsets (machine tools do the same:
unidirectional positioning). A geometry calibration from poses measured the same way absorbs the
ECU's (a fixed fraction of a count: the AD offsets); the play's lag is a constant pose offset, which no
geometry parameter is, so the fit absorbs it only in part (docs/commissioning.md, accuracy through the
twin). With ``offset`` ``d`` (per DOF, from the profile's
``motion.final_approach``) a goto to ``goal`` therefore goes first to the **via** pose

    via = max(min(start, goal − d), workspace minimum)        (per DOF)

and then rises to ``goal`` on a straight line, from rest to rest (each DOF monotonic). A DOF that
starts at least ``d`` below its goal does not move in the first segment (``via = start`` there); when
every DOF does, no via is needed. Near the workspace's lower face the via is cut at the face and the
approach in that DOF is shorter than ``d`` (named in :attr:`ApproachVia.short`). ``d`` must exceed
twice the play band so the implement changes side even from the opposite extreme.

A DOF with a negative ``d`` (the profile's ``side = "above"``) is the mirror image: the via lies
``|d|`` above the goal, ``via = min(max(start, goal − d), workspace maximum)``, and the move ends
falling.

The implement then rests behind the mechanism by the play's half-band (the lag). With the lag known
(``motion.final_approach.lag``, from a calibration that measured both sides) the planner aims the
mechanism at ``goal + sign · lag`` so the implement rests on the goal (backlash compensation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from planner.model.types import CONTROLLED_POSE_NAMES

__all__ = ["ApproachVia", "final_approach_via"]

_TOL = 1e-9


@dataclass(frozen=True)
class ApproachVia:
    """The via pose of a final approach (x, z, roll, pitch; None: the straight move already rises by the
    offset in every DOF) and the DOF whose approach the workspace's lower face shortens."""

    via: np.ndarray | None
    short: tuple[str, ...]


def final_approach_via(
    start: ArrayLike, goal: ArrayLike, offset: ArrayLike, lower: ArrayLike, upper: ArrayLike | None = None
) -> ApproachVia:
    """The via pose for a final approach from ``start`` to ``goal`` rising by ``offset`` (negative: falling by
    its size; module docstring); ``lower``, ``upper``: the workspace minimum and maximum (``upper`` needed
    only with a negative offset). All (4,) in x, z, roll, pitch [m, m, rad, rad]."""
    p0, p1 = np.asarray(start, float), np.asarray(goal, float)
    d, lo = np.asarray(offset, float), np.asarray(lower, float)
    hi = np.full(4, np.inf) if upper is None else np.asarray(upper, float)
    rising = d >= 0.0
    via = np.where(rising, np.maximum(np.minimum(p0, p1 - d), lo), np.minimum(np.maximum(p0, p1 - d), hi))
    short = tuple(
        k for k, v, g, dd in zip(CONTROLLED_POSE_NAMES, via, p1, d, strict=True) if abs(g - v) < abs(dd) - _TOL
    )
    if np.all(np.abs(via - p0) <= _TOL):
        return ApproachVia(None, short)
    return ApproachVia(via, short)
