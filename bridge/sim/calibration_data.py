"""Measurement data for a geometry calibration, taken from the twin's true machine.

For each pose (x, z, roll, pitch) the planner's nominal exact inverse gives the actuators, the
nominal AD map their counts, rounded to whole counts (the ECU holds count set-points); the twin's
pistons sit at those counts, so the AD reading is exactly those counts. The true machine
(:class:`~bridge.sim.truth.TrueMachine`: truth AD map, truth geometry, rigid implement, pin play in
the order the poses are visited) gives the implement's true pose and points, and the
:class:`~bridge.sim.truth.Instrument` reads them with its noise.

Pin play makes a reading depend on the direction the pose was approached from (the implement lags
the mechanism by up to the play band). ``approach="both"`` (the default, the recommended operator
procedure) measures every pose twice: approached from below in every DOF (from the pose minus
:data:`APPROACH_OFFSET`) and from above; the two rows average the play out. ``approach="direct"``
measures each pose once, straight from the previous one. The rows are what
:mod:`planner.calibration.measurements` reads (:func:`calibration_csv`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from bridge.sim.truth import Instrument, InstrumentNoise, MachineTruth, TrueMachine, TruthError
from planner.calibration.measurements import MEASURED_COLUMNS, measurements_csv
from planner.model.exact_inverse import ExactInverse
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import CONTROLLED_POSE_NAMES, KinematicsError

__all__ = ["APPROACH_OFFSET", "TwinMeasurements", "calibration_csv", "measure_twin", "true_poses"]

#: how far before a pose (x, z [m], roll, pitch [rad]) the approach starts: beyond any play band (≤ 3.3 mrad)
APPROACH_OFFSET = np.array([0.004, 0.004, 0.006, 0.006])


@dataclass(frozen=True)
class TwinMeasurements:
    """AD readings (N, 5, whole counts), measured outputs (N, 15, NaN = not measured; MEASURED_COLUMNS
    order) and the true outputs (N, 15; the pose rows x, z, roll, pitch and the points when asked)."""

    counts: np.ndarray
    measured: np.ndarray
    true: np.ndarray


def _counts_of_poses(model: HitchModel, poses: np.ndarray, quantise: bool) -> np.ndarray:
    inv = ExactInverse(model)
    sc = SensorScaling(model.profile)
    out = []
    for p in poses:
        q = inv.solve(p)[0]
        c = sc.counts_min + (q - sc.si_min) / sc.resolution
        out.append(np.rint(c) if quantise else c)
    return np.array(out)


def _poses(poses: ArrayLike) -> np.ndarray:
    p = np.asarray(poses, dtype=float)
    if p.ndim != 2 or p.shape[1] != 4 or not np.all(np.isfinite(p)):
        raise TruthError("poses must be an (N, 4) array of finite x, z, roll, pitch [m, rad]")
    return p


def measure_twin(
    model: HitchModel,
    truth: MachineTruth,
    poses: ArrayLike,
    *,
    noise: InstrumentNoise | str = "station",
    points: Sequence[str] = (),
    seed: int = 0,
    rigid_span: bool = True,
    approach: Literal["both", "direct"] = "both",
) -> TwinMeasurements:
    """Visit ``poses`` (N, 4) on the twin in order (module docstring) and measure each one (``approach="both"``:
    rows 2k and 2k+1 are pose k approached from below and from above)."""
    if approach not in ("both", "direct"):
        raise TruthError(f"approach must be both or direct, got {approach!r}")
    p = _poses(poses)
    counts = _counts_of_poses(model, p, quantise=True)
    machine = TrueMachine(truth, model.category, rigid_span=rigid_span)
    inst = Instrument(noise, seed=seed)
    visits: list[tuple[np.ndarray, np.ndarray | None]] = []
    for k in range(p.shape[0]):
        if approach == "direct":
            visits.append((counts[k], None))
            continue
        for sign in (-1.0, 1.0):
            try:
                before = _counts_of_poses(model, p[k : k + 1] + sign * APPROACH_OFFSET, quantise=False)[0]
            except KinematicsError:
                before = None
            visits.append((counts[k], before))
    n = len(visits)
    measured = np.full((n, 15), np.nan)
    true = np.full((n, 15), np.nan)
    rows = [MEASURED_COLUMNS.index(n) for n in CONTROLLED_POSE_NAMES]
    for k, (c, before) in enumerate(visits):
        if before is not None:
            machine.observe(before)
        pose = machine.observe(c)
        reading = inst.measure(machine, tuple(points))
        true[k, rows] = pose.controlled()
        measured[k, rows] = [reading.pose[n] for n in CONTROLLED_POSE_NAMES]
        tp = machine.points(tuple(points)) if points else {}
        for name in points:
            i = MEASURED_COLUMNS.index(f"{name}_x")
            true[k, i : i + 3] = tp[name]
            measured[k, i : i + 3] = reading.points[name]
    return TwinMeasurements(np.array([v[0] for v in visits]), measured, true)


def true_poses(
    model: HitchModel, truth: MachineTruth, commanded: ArrayLike, *, quantise: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Where the true machine goes when ``model``'s exact inverse commands poses (N, 4): (true poses (N, 4),
    piston counts (N, 5)). ``model`` is the planner's (nominal or calibrated) model; ``quantise`` rounds
    the commanded counts (off: the pistons at exactly the commanded counts). No play (fresh machine
    per pose)."""
    p = _poses(commanded)
    counts = _counts_of_poses(model, p, quantise=quantise)
    first = TrueMachine(truth, model.category)
    out = []
    for c in counts:
        machine = TrueMachine(truth, model.category, model=first.model)  # fresh play state, shared model
        out.append(machine.observe(c).controlled())
    return np.array(out), counts


def calibration_csv(data: TwinMeasurements) -> str:
    """The measurement file (CSV, counts) of twin measurements."""
    return measurements_csv(data.counts, data.measured)
