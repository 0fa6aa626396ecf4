"""Range checks of the offline commands' inputs, before any kinematics runs.

A value outside its range is refused with the flag, the value and the allowed range, every
violated field at once, and the unit hint of the service (``did you mean mm?`` /
``did you mean degrees?``) when the value would fit read in mm or degrees. The hint and the
workspace wording are the planner's and the service's own (:func:`planner.errors.unit_hint`,
:func:`bridge.service.schemas.check_pose_in_workspace`), not a second copy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from bridge.cli.errors import CLIError
from bridge.service.schemas import RequestError, check_pose_in_workspace
from planner.errors import unit_hint
from planner.model.types import ACTUATOR_NAMES, ACTUATOR_UNITS

__all__ = ["ACTUATOR_UNITS", "actuator_problems", "check_actuators", "check_pose_ranges", "pose_problems"]


def actuator_problems(
    q: ArrayLike, lower: ArrayLike, upper: ArrayLike, labels: Mapping[str, str] | None = None
) -> list[str]:
    """One text per actuator of ``q`` (actuator order, SI) outside ``[lower, upper]``, naming its
    flag (``--lift``), the value, the range and the unit hint; ``labels`` adds a description."""
    out = []
    rows = (np.asarray(a, dtype=float).reshape(-1) for a in (q, lower, upper))
    for name, v, lo, hi in zip(ACTUATOR_NAMES, *rows, strict=True):
        v, lo, hi = float(v), float(lo), float(hi)
        unit = ACTUATOR_UNITS[name]
        label = f" ({labels[name]})" if labels and name in labels else ""
        if not math.isfinite(v):
            out.append(f"--{name}{label} must be a finite number, got {v}")
            continue
        if lo - 1e-9 <= v <= hi + 1e-9:
            continue
        out.append(
            f"--{name} = {v:.6g} {unit}{label} is outside its range {lo:.4g}..{hi:.4g} {unit}"
            + unit_hint(v, lo, hi, unit)
        )
    return out


def check_actuators(q: ArrayLike, lower: ArrayLike, upper: ArrayLike, labels: Mapping[str, str] | None = None) -> None:
    """:class:`CLIError` naming every actuator of ``q`` outside its stroke (:func:`actuator_problems`)."""
    problems = actuator_problems(q, lower, upper, labels)
    if problems:
        head = "actuator outside its stroke" if len(problems) == 1 else "actuators outside their strokes"
        raise CLIError(f"{head}: " + "; ".join(problems))


def pose_problems(
    pose: Mapping[str, Any] | None, workspace: Mapping[str, Sequence[float]] | None, *, flag: str, what: str
) -> str | None:
    """The service's workspace refusal of the (partial) ``pose`` given with ``flag`` — every DOF
    outside ``workspace`` with its range and unit hint — or None when all lie inside."""
    try:
        check_pose_in_workspace(pose or {}, workspace, key=flag, what=what)
    except RequestError as exc:
        return str(exc)
    return None


def check_pose_ranges(
    *checks: tuple[Mapping[str, Any] | None, str, str], workspace: Mapping[str, Sequence[float]] | None
) -> None:
    """:class:`CLIError` naming every DOF outside ``workspace`` of every ``(pose, flag, what)``."""
    problems = [p for pose, flag, what in checks if (p := pose_problems(pose, workspace, flag=flag, what=what))]
    if problems:
        raise CLIError("; ".join(problems))
