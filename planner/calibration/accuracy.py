"""The thesis's field accuracy test (thesis tables 3-8 … 3-10) as pure code: the pose sequence and the statistics.

The thesis deflected each DOF "twice positive, then negative, then several at once" from a home
pose, measured the implement with a tape (the heights of the implement frame's four corners and a
plumb line for the lateral position) and reported per DOF ``E`` (mean error), ``|E|`` (mean
absolute error), ``|E|max`` (largest absolute error) and ``TT`` (repeatability: the standard
deviation of repeated measurements of one point).

The sequence (:func:`thesis_sequence`). The thesis gives no deflection sizes; chosen here (about
two thirds of the restricted workspace of the thesis profile about its neutral pose, documented
assumption, :class:`Deflections`): x ±40 mm, z ±100 mm, roll ±40 mrad, pitch ±40 mrad. For each
DOF in turn: ``+d``, home, ``+d``, home, ``−d``, home, ``−d``, home; then the combined
deflections, each twice with home between: ``(+x/2, +z/2, +roll/2, −pitch/2)`` and its negative.
Only the deflected poses are measured (home is the approach; it is not a test point). A pose is
measured once per visit; each pose is visited twice.

The statistics (:func:`accuracy_statistics`), per DOF over every measured pose (all DOF are read
at every pose), error = measured − commanded:

* ``E = mean(e)``, ``|E| = mean(|e|)``, ``|E|max = max(|e|)``;
* ``TT``: the pooled sample standard deviation of the repeated visits to the same pose,
  ``sqrt(Σ_poses Σ_visits (e − ē_pose)² / Σ_poses (n_pose − 1))`` (the thesis's "standard deviation
  of repeated measurements of one point", pooled over the points).

Units: SI (m, rad) everywhere here; mm and mrad only where a report prints them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from planner.errors import HitchInputError
from planner.model.types import CONTROLLED_POSE_NAMES

__all__ = [
    "THESIS_ACCURACY",
    "AccuracyError",
    "AccuracyPose",
    "Deflections",
    "DofStatistics",
    "accuracy_statistics",
    "thesis_sequence",
]

_DOF = CONTROLLED_POSE_NAMES  # x, z, roll, pitch


class AccuracyError(HitchInputError):
    """A sequence or a set of measurements that the accuracy test cannot use; names the field and range."""


def _size(name: str, v: object, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and 0.0 < v <= hi):
        raise AccuracyError(f"{name} must be a number in (0, {hi:g}], got {v!r}")
    return float(v)


@dataclass(frozen=True)
class Deflections:
    """Deflection sizes of the test [m, m, rad, rad] (the thesis gives none: module docstring)."""

    x_m: float = 0.040
    z_m: float = 0.100
    roll_rad: float = 0.040
    pitch_rad: float = 0.040

    def __post_init__(self) -> None:
        for name, hi in (("x_m", 0.5), ("z_m", 1.0), ("roll_rad", 0.5), ("pitch_rad", 0.5)):
            object.__setattr__(self, name, _size(f"deflections.{name}", getattr(self, name), hi))

    def as_array(self) -> np.ndarray:
        return np.array([self.x_m, self.z_m, self.roll_rad, self.pitch_rad])


@dataclass(frozen=True)
class AccuracyPose:
    """One step of the sequence: ``label`` names the pose (visits of one pose share it), ``offset`` is
    the deflection from home (x, z, roll, pitch; m, rad); ``measure`` is False for the home returns."""

    label: str
    offset: tuple[float, float, float, float]
    measure: bool = True

    def goal(self, home: ArrayLike) -> dict[str, float]:
        """The commanded pose: home + offset, as a goal mapping (x, z, roll, pitch)."""
        h = np.asarray(home, dtype=float).reshape(-1)
        if h.size != 4 or not np.all(np.isfinite(h)):
            raise AccuracyError(f"home must be 4 finite numbers (x, z, roll, pitch), got {home!r}")
        return {k: float(v) for k, v in zip(_DOF, h + np.asarray(self.offset), strict=True)}


def thesis_sequence(
    deflections: Deflections | None = None, *, dofs: Sequence[str] = _DOF, combined: bool = True
) -> tuple[AccuracyPose, ...]:
    """The thesis's pose sequence (module docstring) as a tuple of :class:`AccuracyPose`.

    ``dofs``: the single-DOF deflections to include (default all four, in order x, z, roll, pitch);
    ``combined``: append the combined deflections.
    """
    d = (deflections if deflections is not None else Deflections()).as_array()
    unknown = [n for n in dofs if n not in _DOF]
    if unknown or not (dofs or combined):
        raise AccuracyError(f"dofs: unknown or none {list(dofs)!r}; allowed: {', '.join(_DOF)}")
    repeated = sorted({n for n in dofs if list(dofs).count(n) > 1})
    if repeated:
        raise AccuracyError(f"dofs: {', '.join(repeated)} given twice; each of {', '.join(_DOF)} at most once")
    home = AccuracyPose("home", (0.0, 0.0, 0.0, 0.0), measure=False)
    steps: list[AccuracyPose] = []
    for name in dofs:
        i = _DOF.index(name)
        for sign, tag in ((1.0, "+"), (1.0, "+"), (-1.0, "-"), (-1.0, "-")):
            off = np.zeros(4)
            off[i] = sign * d[i]
            steps += [AccuracyPose(f"{name}{tag}", (off[0], off[1], off[2], off[3])), home]
    if combined:
        mixed = 0.5 * d * np.array([1.0, 1.0, 1.0, -1.0])
        for sign, tag in ((1.0, "+"), (1.0, "+"), (-1.0, "-"), (-1.0, "-")):
            off = sign * mixed
            steps += [AccuracyPose(f"combined{tag}", (off[0], off[1], off[2], off[3])), home]
    return tuple(steps)


@dataclass(frozen=True)
class DofStatistics:
    """Accuracy of one DOF [m or rad]: mean error, mean absolute error, largest absolute error, repeatability."""

    mean: float
    mean_abs: float
    max_abs: float
    repeatability: float
    n: int | None  # poses measured; None where not known (the thesis's tables give no count)

    def as_dict(self) -> dict[str, float | int | None]:
        return {
            "E": self.mean,
            "abs_E": self.mean_abs,
            "abs_E_max": self.max_abs,
            "TT": self.repeatability,
            "n": self.n,
        }


def accuracy_statistics(commanded: ArrayLike, measured: ArrayLike, labels: Sequence[str]) -> dict[str, DofStatistics]:
    """Per DOF (x, z, roll, pitch) statistics of ``measured − commanded`` ((N, 4) arrays, SI); ``labels``
    names the pose of each row (rows with the same label are repeated visits, for ``TT``)."""
    c = np.asarray(commanded, dtype=float)
    m = np.asarray(measured, dtype=float)
    if c.ndim != 2 or c.shape[1] != 4 or m.shape != c.shape or len(c) == 0:
        raise AccuracyError(
            f"commanded and measured must be (N >= 1, 4) arrays of equal shape, got {c.shape}, {m.shape}"
        )
    if len(labels) != len(c):
        raise AccuracyError(f"labels must name each of the {len(c)} rows, got {len(labels)}")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(m))):
        raise AccuracyError("commanded and measured poses must be finite")
    e = m - c
    groups: dict[str, list[int]] = {}
    for k, lab in enumerate(labels):
        groups.setdefault(str(lab), []).append(k)
    dof_ss = np.zeros(4)
    dof = 0
    for rows in groups.values():
        if len(rows) > 1:
            g = e[rows]
            dof_ss += ((g - g.mean(axis=0)) ** 2).sum(axis=0)
            dof += len(rows) - 1
    tt = np.sqrt(dof_ss / dof) if dof > 0 else np.full(4, math.nan)
    return {
        name: DofStatistics(
            mean=float(e[:, i].mean()),
            mean_abs=float(np.abs(e[:, i]).mean()),
            max_abs=float(np.abs(e[:, i]).max()),
            repeatability=float(tt[i]),
            n=len(e),
        )
        for i, name in enumerate(_DOF)
    }


def _row(e_mm: float, a_mm: float, m_mm: float, tt_mm: float, scale: float = 1e-3) -> DofStatistics:
    return DofStatistics(e_mm * scale, a_mm * scale, m_mm * scale, tt_mm * scale, None)


#: The thesis's field figures (tables 3-8 hybrid, 3-9 DLS, 3-10 geometric), SI (m, rad); ``n`` not known (None:
#: the thesis gives no count of measured poses; JSON null, where 0 read as "no measurements").
THESIS_ACCURACY: Mapping[str, Mapping[str, DofStatistics]] = {
    "hybrid (3-8)": {
        "x": _row(3.81, 8.9, 30, 17.9),
        "z": _row(-2, 8.36, 40, 2.23),
        "roll": _row(-0.18, 4.4, 17, 3.3),
        "pitch": _row(-39, 39, 62, 2.3),
    },
    "DLS (3-9)": {
        "x": _row(3.45, 8.9, 30, 13.4),
        "z": _row(-5.01, 9.8, 35, 5.7),
        "roll": _row(-0.16, 14.5, 47, 11.2),
        "pitch": _row(-17, 17.6, 33, 4.7),
    },
    "geometric (3-10)": {
        "x": _row(3.8, 6.36, 30, 11),
        "z": _row(-2.8, 9.5, 55, 5),
        "roll": _row(1, 9, 60, 3),
        "pitch": _row(-28, 28, 100, 0),
    },
}
