"""Value types shared by every layer: actuators, poses, kinematic states.

All values are SI: metres for lengths, radians for angles.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from planner.errors import HitchInputError

__all__ = [
    "ACTUATOR_NAMES",
    "POSE_NAMES",
    "CONTROLLED_POSE_NAMES",
    "CONTROLLED_POSE_UNITS",
    "ACTUATOR_UNITS",
    "Actuators",
    "Pose",
    "HitchState",
    "KinematicsError",
    "ModelInputError",
]

#: Order of the actuator vector everywhere (arrays, CAN references, plots).
ACTUATOR_NAMES: tuple[str, ...] = ("lift", "tilt", "top", "left", "right")
#: Order of the full pose vector.
POSE_NAMES: tuple[str, ...] = ("x", "y", "z", "roll", "pitch", "yaw")
#: The four controlled degrees of freedom of the implement.
CONTROLLED_POSE_NAMES: tuple[str, ...] = ("x", "z", "roll", "pitch")
#: SI unit of each controlled degree of freedom (lengths in m, angles in rad), in that order.
CONTROLLED_POSE_UNITS: dict[str, str] = {"x": "m", "z": "m", "roll": "rad", "pitch": "rad"}
#: SI unit of each actuator (the lift is an angle, the others are lengths), in :data:`ACTUATOR_NAMES` order.
ACTUATOR_UNITS: dict[str, str] = {"lift": "rad", "tilt": "m", "top": "m", "left": "m", "right": "m"}
#: what a coordinate may be (besides finite, not bool)
_NUMBERS = (int, float, np.integer, np.floating)


class KinematicsError(HitchInputError):
    """An actuator vector or pose no mechanism can take; the message names the cause."""


class ModelInputError(HitchInputError):
    """An argument the model does not accept (wrong size, not a finite number); names the field.

    Distinct from :class:`KinematicsError`: a well-formed vector the mechanism cannot take is a
    kinematics error, a malformed one is this.
    """


@dataclass(frozen=True)
class Actuators:
    """The five actuator coordinates of the hitch.

    ``lift`` is the lift-arm angle theta_E [rad]; ``tilt`` (right lift rod), ``top``
    (top link), ``left`` and ``right`` (sway limiters) are pin-to-pin lengths [m].
    """

    lift: float
    tilt: float
    top: float
    left: float
    right: float

    def __post_init__(self) -> None:
        """:class:`ModelInputError` naming the field for anything but a finite number (NaN and text were kept and
        failed, or gave NaN, wherever the value went). One sum tests the common case (5 finite numbers, ~0.1 µs
        of a construction's 0.7 µs: forward kinematics builds one per call); the fields are named only on failure."""
        try:
            fine = math.isfinite(self.lift + self.tilt + self.top + self.left + self.right)
        except (TypeError, ValueError):
            fine = False
        kinds = (type(self.lift), type(self.tilt), type(self.top), type(self.left), type(self.right))
        if not fine or bool in kinds:
            for name in ACTUATOR_NAMES:
                v = getattr(self, name)
                if isinstance(v, bool) or not isinstance(v, _NUMBERS) or not math.isfinite(v):
                    raise ModelInputError(
                        f"Actuators.{name} must be a finite number [{ACTUATOR_UNITS[name]}], got {v!r}"
                    )

    def as_array(self) -> np.ndarray:
        return np.array([self.lift, self.tilt, self.top, self.left, self.right], dtype=float)

    @classmethod
    def from_array(cls, values: ArrayLike) -> Actuators:
        v = np.asarray(values, dtype=float).reshape(-1)
        if v.size != 5:
            raise ModelInputError(f"actuator vector needs 5 values (lift, tilt, top, left, right), got {v.size}")
        return cls(*(float(x) for x in v))

    @classmethod
    def from_mapping(cls, values: Mapping[str, float]) -> Actuators:
        missing = [n for n in ACTUATOR_NAMES if n not in values]
        unknown = sorted(str(k) for k in values if k not in ACTUATOR_NAMES)
        if missing or unknown:  # a misspelt "rigth" was not named, only the "right" it left missing
            said = [f"missing field(s) {', '.join(missing)}"] if missing else []
            said += [f"unknown field(s) {', '.join(unknown)}"] if unknown else []
            raise ModelInputError(f"actuators: {'; '.join(said)}; allowed: {', '.join(ACTUATOR_NAMES)}")
        return cls(*(float(values[n]) for n in ACTUATOR_NAMES))

    def as_dict(self) -> dict[str, float]:
        return {n: getattr(self, n) for n in ACTUATOR_NAMES}


@dataclass(frozen=True)
class Pose:
    """Pose of the tool point T and the implement, in the tractor frame.

    x, y, z [m]; roll, pitch, yaw [rad]. See README "Frames and signs".
    """

    x: float
    y: float
    z: float
    roll: float
    pitch: float
    yaw: float

    def as_array(self) -> np.ndarray:
        return np.array([self.x, self.y, self.z, self.roll, self.pitch, self.yaw], dtype=float)

    @classmethod
    def from_array(cls, values: ArrayLike) -> Pose:
        v = np.asarray(values, dtype=float).reshape(-1)
        if v.size != 6:
            raise ModelInputError(f"pose vector needs 6 values (x, y, z, roll, pitch, yaw), got {v.size}")
        return cls(*(float(x) for x in v))

    def controlled(self) -> np.ndarray:
        """The four controlled DOF (x, z, roll, pitch)."""
        return np.array([self.x, self.z, self.roll, self.pitch], dtype=float)

    def as_dict(self) -> dict[str, float]:
        return {n: getattr(self, n) for n in POSE_NAMES}


@dataclass(frozen=True)
class HitchState:
    """Result of forward kinematics: actuators, pose and every named point [m]."""

    actuators: Actuators
    pose: Pose
    points: Mapping[str, np.ndarray] = field(repr=False)
    #: lower-link angles theta_xl, theta_zl, theta_xr, theta_zr [rad] (thesis 2.19-2.20)
    link_angles: tuple[float, float, float, float] = (math.nan,) * 4
    #: top-link direction angles relative to its mount reference: (yaw, pitch) [rad]
    top_link_angles: tuple[float, float] = (math.nan, math.nan)
    #: distance |L - R| [m]; equals the implement span when an implement is attached
    lower_span: float = math.nan
