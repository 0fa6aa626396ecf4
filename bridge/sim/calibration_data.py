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

The piston inside its count. The ECU drives a piston until its AD reading equals the commanded
whole count, so the true piston lies anywhere in that count's band: its unquantised count on the
true AD map is the commanded count ± 0.5. ``dither=True`` (off by default: the pistons exactly at the
whole counts) draws it uniformly in that band (seeded), in :func:`measure_twin` and
:func:`true_poses` alike.

:func:`true_poses` evaluates a profile: where the true machine goes when the profile's exact
inverse commands poses. Idealised (the defaults): the pistons at exactly the commanded, unrounded
counts, play centred. Physical (``quantise=True, dither=True, play="random"``): the commanded counts
rounded to whole counts, each piston anywhere in its count's band, and the pin play as the twin has
it, every pose approached from a random side in every DOF (from the pose ± :data:`APPROACH_OFFSET`,
so the implement lags by the full play band in each DOF).
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

__all__ = ["APPROACH_OFFSET", "TwinMeasurements", "calibration_csv", "measure_twin", "mirrored_approach", "true_poses"]

#: how far before a pose (x, z [m], roll, pitch [rad]) the approach starts: beyond any play band (≤ 3.3 mrad)
APPROACH_OFFSET = np.array([0.004, 0.004, 0.006, 0.006])


@dataclass(frozen=True)
class TwinMeasurements:
    """AD readings (N, 5, whole counts), measured outputs (N, 15, NaN = not measured; MEASURED_COLUMNS
    order), the true outputs (N, 15; the pose rows x, z, roll, pitch and the points when asked), the side
    each row was approached from in every DOF (N,: −1 below, +1 above, 0 neither) and where the pin play left
    the implement (N, 4: its true pose minus the true mechanism's, :attr:`TrueMachine.play_offset`)."""

    counts: np.ndarray
    measured: np.ndarray
    true: np.ndarray
    sides: np.ndarray
    play_offset: np.ndarray


class _Commander:
    """The planner side: commanded AD counts of poses through ``model``'s exact inverse and nominal map."""

    def __init__(self, model: HitchModel) -> None:
        self.inv = ExactInverse(model)
        self.sc = SensorScaling(model.profile)

    def counts(self, poses: np.ndarray, quantise: bool) -> np.ndarray:
        out = []
        for p in poses:
            q = self.inv.solve(p)[0]
            c = self.sc.counts_of(q)
            out.append(np.rint(c) if quantise else c)
        return np.array(out)


def _seed(seed: object) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < 2**63:
        raise TruthError(f"seed must be an integer in [0, 2^63), got {seed!r}")
    return int(seed)


def _flag(name: str, value: object) -> bool:
    if not isinstance(value, bool):
        raise TruthError(f"{name} must be a bool, got {value!r}")
    return value


def _piston_counts(counts: np.ndarray, dither: bool, rng: np.random.Generator) -> np.ndarray:
    """The pistons' unquantised counts on the true map: the reading, or (``dither``) uniform in its ± 0.5 band."""
    return counts + rng.uniform(-0.5, 0.5, counts.shape) if dither else counts


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
    approach: Literal["both", "direct"] | None = None,
    dither: bool = False,
    by: Literal["static", "goto"] = "static",
) -> TwinMeasurements:
    """Visit ``poses`` (N, 4) on the twin in order (module docstring) and measure each one (``approach="both"``,
    the default: rows 2k and 2k+1 are pose k approached from below and from above). ``dither``: each piston
    anywhere in its count's band (module docstring; drawn from ``seed``); the AD readings stay the whole counts.

    ``by="goto"``: the operator's procedure on the running twin instead — each pose reached by a real goto
    of ``model``'s planner over CAN (with the profile's ``motion.final_approach``, if any; the pistons where
    the ECU leaves them), the readings the link's counts at rest (:func:`~bridge.sim.accuracy_run.visit_poses`;
    ``dither`` and ``rigid_span`` do not apply). One row per pose (``approach="direct"``, the default here), its
    side the final approach's; or ``approach="both"`` (needs the final approach): the poses visited once with
    the profile's approach and once with its mirror image (``side`` flipped), rows N + k the second pass."""
    if approach is not None and approach not in ("both", "direct"):
        raise TruthError(f"approach must be both or direct, got {approach!r}")
    if by not in ("static", "goto"):
        raise TruthError(f"by must be static or goto, got {by!r}")
    dither = _flag("dither", dither)
    p = _poses(poses)
    inst = Instrument(noise, seed=seed)
    if by == "goto":
        return _measure_by_goto(model, truth, p, inst, tuple(points), _seed(seed), approach == "both")
    approach = "both" if approach is None else approach
    rng = np.random.default_rng([_seed(seed), 1])
    cmd = _Commander(model)
    counts = cmd.counts(p, quantise=True)
    machine = TrueMachine(truth, model.category, rigid_span=rigid_span)
    visits: list[tuple[np.ndarray, np.ndarray | None]] = []
    for k in range(p.shape[0]):
        if approach == "direct":
            visits.append((counts[k], None))
            continue
        for sign in (-1.0, 1.0):
            try:
                before = cmd.counts(p[k : k + 1] + sign * APPROACH_OFFSET, quantise=False)[0]
            except KinematicsError:
                before = None
            visits.append((counts[k], before))
    n = len(visits)
    measured = np.full((n, 15), np.nan)
    true = np.full((n, 15), np.nan)
    play = np.full((n, 4), np.nan)
    rows = [MEASURED_COLUMNS.index(n) for n in CONTROLLED_POSE_NAMES]
    for k, (c, before) in enumerate(visits):
        if before is not None:
            machine.observe(before)
        pose = machine.observe(_piston_counts(c, dither, rng))
        play[k] = machine.play_offset
        reading = inst.measure(machine, tuple(points))
        true[k, rows] = pose.controlled()
        measured[k, rows] = [reading.pose[n] for n in CONTROLLED_POSE_NAMES]
        tp = machine.points(tuple(points)) if points else {}
        for name in points:
            i = MEASURED_COLUMNS.index(f"{name}_x")
            true[k, i : i + 3] = tp[name]
            measured[k, i : i + 3] = reading.points[name]
    sides = np.array([0.0 if before is None else (-1.0 if k % 2 == 0 else 1.0) for k, (_, before) in enumerate(visits)])
    return TwinMeasurements(np.array([v[0] for v in visits]), measured, true, sides, play)


def mirrored_approach(model: HitchModel) -> HitchModel:
    """``model`` with its ``motion.final_approach`` ending from the other side (``side`` flipped; the rest,
    the lag too, kept): the second pass of a two-sided measurement."""
    fa = model.profile.motion.final_approach
    if fa is None:
        raise TruthError(
            f"measuring from both sides by goto (--sides both) needs the profile's motion.final_approach, and "
            f"{model.profile.name} has none: add [motion.final_approach] (docs/commissioning.md) and give that "
            "profile with --profile"
        )
    flipped = fa.model_copy(update={"side": "above" if fa.side == "below" else "below"})
    motion = model.profile.motion.model_copy(update={"final_approach": flipped})
    return HitchModel(model.profile.model_copy(update={"motion": motion}), model.category)


def _measure_by_goto(
    model: HitchModel,
    truth: MachineTruth,
    poses: np.ndarray,
    inst: Instrument,
    points: tuple[str, ...],
    seed: int,
    both: bool,
) -> TwinMeasurements:
    passes = [model, mirrored_approach(model)] if both else [model]
    parts = [_goto_pass(m, truth, poses, inst, points, seed) for m in passes]
    return TwinMeasurements(
        *(
            np.concatenate([getattr(t, f) for t in parts])
            for f in ("counts", "measured", "true", "sides", "play_offset")
        )
    )


def _goto_pass(
    model: HitchModel, truth: MachineTruth, poses: np.ndarray, inst: Instrument, points: tuple[str, ...], seed: int
) -> TwinMeasurements:
    """One pass of :func:`_measure_by_goto`: every pose by a goto of ``model``'s planner, its side the approach's."""
    from bridge.sim.accuracy_run import AccuracyRunSettings, visit_poses  # the rig: only for this procedure

    v = visit_poses(model, poses, truth, AccuracyRunSettings(seed=seed), instrument=inst, points=points)
    fa = model.profile.motion.final_approach
    side = 0.0 if fa is None else -fa.sign  # rising (below): −1
    n = poses.shape[0]
    measured, true = np.full((n, 15), np.nan), np.full((n, 15), np.nan)
    rows = [MEASURED_COLUMNS.index(c) for c in CONTROLLED_POSE_NAMES]
    for k, reading in enumerate(v.measurements):
        if reading is None:  # visit_poses raises on a refused pose before; never measured
            raise TruthError(f"pose {k} was not measured")
        true[k, rows] = v.true[k]
        measured[k, rows] = [reading.pose[c] for c in CONTROLLED_POSE_NAMES]
        for name in points:
            i = MEASURED_COLUMNS.index(f"{name}_x")
            true[k, i : i + 3] = v.points[k][name]
            measured[k, i : i + 3] = reading.points[name]
    assert v.play_offset is not None  # visit_poses records it
    return TwinMeasurements(v.counts, measured, true, np.full(n, side), v.play_offset)


def true_poses(
    model: HitchModel,
    truth: MachineTruth,
    commanded: ArrayLike,
    *,
    quantise: bool = False,
    dither: bool = False,
    play: Literal["centred", "random"] = "centred",
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Where the true machine goes when ``model``'s exact inverse commands poses (N, 4): (true poses (N, 4),
    commanded counts (N, 5)). ``model`` is the planner's (nominal or calibrated) model. ``quantise`` rounds
    the commanded counts (off: the pistons at exactly the commanded counts); ``dither`` (needs
    ``quantise``) puts each piston anywhere in its count's band; ``play="random"`` approaches every pose
    from a random side in every DOF (``"centred"``: play centred). Each pose is a fresh machine; ``seed``
    draws the band positions and the sides (module docstring)."""
    quantise, dither = _flag("quantise", quantise), _flag("dither", dither)
    if dither and not quantise:
        raise TruthError("dither needs quantise=True (the piston sits in the band of a whole commanded count)")
    if play not in ("centred", "random"):
        raise TruthError(f"play must be centred or random, got {play!r}")
    rng = np.random.default_rng([_seed(seed), 2])
    p = _poses(commanded)
    cmd = _Commander(model)
    counts = cmd.counts(p, quantise=quantise)
    first = TrueMachine(truth, model.category)
    out = []
    for k, c in enumerate(counts):
        machine = TrueMachine(truth, model.category, model=first.model)  # fresh play state, shared model
        if play == "random":
            side = rng.choice([-1.0, 1.0], 4)
            for s in (side, -side):  # the other side if the approach start is out of reach
                try:
                    machine.observe(cmd.counts(p[k : k + 1] + s * APPROACH_OFFSET, quantise=False)[0])
                    break
                except KinematicsError:
                    continue
        out.append(machine.observe(_piston_counts(c, dither, rng)).controlled())
    return np.array(out), counts


def calibration_csv(data: TwinMeasurements, labels: Sequence[str] | None = None) -> str:
    """The measurement file (CSV, counts) of twin measurements, with the ``approach`` column where a row's side
    is known; ``labels`` one per row (default p1, p2 …)."""
    sides = data.sides if np.any(data.sides != 0.0) else None
    return measurements_csv(data.counts, data.measured, labels=labels, sides=sides)
