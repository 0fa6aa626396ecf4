"""Result type and target validation shared by the hitch IK solver and the thesis baselines."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from planner.errors import unit_hint
from planner.ik_qp.errors import IKInputError
from planner.model.types import Actuators, Pose

__all__ = ["Target", "IKResult", "check_target"]

_TARGET_FIELDS = ("x", "z", "roll", "pitch")
#: Accepted magnitudes: positions [m] and angles [rad] far beyond any hitch, still finite.
_TARGET_RANGE = {"x": 10.0, "z": 10.0, "roll": math.pi / 2, "pitch": math.pi / 2}


def _finite(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise IKInputError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise IKInputError(f"{name} must be finite, got {v}")
    lim = _TARGET_RANGE[name]
    if abs(v) > lim:
        unit = "m" if name in ("x", "z") else "rad"
        hint = unit_hint(v, -lim, lim, unit)
        raise IKInputError(f"{name} = {v} is outside the accepted range ±{lim:.7g} {unit}{hint}")
    return v


@dataclass(frozen=True)
class Target:
    """Desired implement pose: x, z [m], roll, pitch [rad]; optional task weights (4,).

    Weights say which DOF to favour when the target is out of reach (the nearest
    reachable pose is nearest in the weighted sense), multiplying the solver's own: 1 per metre
    and the mast height d_T^U per radian, an angle counted as the displacement it causes at the
    mast top (:func:`planner.ik_qp.hitch_ik.default_weights`).
    """

    x: float
    z: float
    roll: float
    pitch: float
    weights: tuple[float, float, float, float] | None = None

    def __post_init__(self):
        for n in _TARGET_FIELDS:
            object.__setattr__(self, n, _finite(n, getattr(self, n)))
        if self.weights is not None:
            w = tuple(self.weights)
            if len(w) != 4:
                raise IKInputError(f"weights must have 4 values (x, z, roll, pitch), got {len(w)}")
            for n, v in zip(_TARGET_FIELDS, w, strict=True):
                if isinstance(v, bool) or not isinstance(v, (int, float, np.floating)) or not math.isfinite(v) or v < 0:
                    raise IKInputError(f"weights.{n} must be a finite number >= 0, got {v!r}")
            if not any(v > 0 for v in w):
                raise IKInputError("weights: at least one weight must be > 0")
            object.__setattr__(self, "weights", tuple(float(v) for v in w))

    def as_array(self) -> np.ndarray:
        return np.array([self.x, self.z, self.roll, self.pitch])


def check_target(target: Target | Mapping[str, float] | Iterable[float]) -> tuple[float, float, float, float]:
    """(x, z, roll, pitch) from a :class:`Target`, a mapping or a 4-sequence; ValueError naming the field."""
    if isinstance(target, Target):
        return target.x, target.z, target.roll, target.pitch
    if isinstance(target, (str, bytes)):  # iterable, but of characters: "abc" read as "got 3 values"
        raise IKInputError(f"target must be a Target, a mapping or 4 numbers, got text {target!r}")
    if isinstance(target, dict):
        missing = [n for n in _TARGET_FIELDS if n not in target]
        unknown = sorted(str(k) for k in target if k not in _TARGET_FIELDS)  # a yaw was silently ignored
        if missing or unknown:  # both named: "ptch" for "pitch" said only "missing field(s) pitch"
            said = [f"missing field(s) {', '.join(missing)}"] if missing else []
            said += [f"unknown field(s) {', '.join(unknown)}"] if unknown else []
            raise IKInputError(f"target: {'; '.join(said)}; allowed: {', '.join(_TARGET_FIELDS)}")
        v = [_finite(n, target[n]) for n in _TARGET_FIELDS]
        return v[0], v[1], v[2], v[3]
    try:
        vals = list(target)
    except TypeError:
        raise IKInputError(f"target must be a Target, a mapping or 4 numbers, got {type(target).__name__}") from None
    if len(vals) != 4:
        raise IKInputError(f"target needs 4 values (x, z, roll, pitch), got {len(vals)}")
    v = [_finite(n, x) for n, x in zip(_TARGET_FIELDS, vals, strict=True)]
    return v[0], v[1], v[2], v[3]


@dataclass(frozen=True)
class IKResult:
    """Outcome of one IK solve.

    ``pose`` is the forward kinematics of ``actuators`` (not the target). ``status``:
    "ok" reached; "limited" out of reach, the nearest reachable pose returned, ``active``
    names the limits that stop it; "failed" with ``reason``. ``residual`` is the largest
    pose error |pose − target| over x, z [m], roll, pitch [rad].
    """

    actuators: Actuators | None
    pose: Pose | None
    status: Literal["ok", "limited", "failed"]
    active: tuple[str, ...] = ()
    iterations: int = 0
    residual: float = math.inf
    solve_time_s: float = 0.0
    reason: str = ""
    extra: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def failed(cls, reason: str, iterations: int = 0, solve_time_s: float = 0.0) -> IKResult:
        return cls(None, None, "failed", (), iterations, math.inf, solve_time_s, reason)

    def to_json(self) -> dict:
        return {
            "status": self.status,
            "actuators": None if self.actuators is None else self.actuators.as_dict(),
            "pose": None if self.pose is None else self.pose.as_dict(),
            "active": list(self.active),
            "iterations": self.iterations,
            "residual": self.residual if math.isfinite(self.residual) else None,
            "solve_time_s": self.solve_time_s,
            **({"reason": self.reason} if self.reason else {}),
        }
