"""Which poses to measure: D-optimal selection over a candidate set of workspace poses.

Candidates are poses (x, z, roll, pitch) of the model's restricted workspace (the box's corners,
face centres and seeded uniform samples), kept when the nominal exact inverse reaches them with
every actuator inside its stroke (a margin of ``margin`` of the stroke from each end). Where the
profile has a ``motion.final_approach``, the box's lower faces move up by its offset (the upper faces
down with ``side = "above"``, both for poses measured from both sides): a goto to a candidate then
rises by the whole offset in every DOF, so the pin play is taken up as in every other goto. (At a
lower face the approach is cut short and the play is left partly taken up; measured there, it biased
calibrated roll by about 1.3 mrad in three of 20 tape-perturbed twins through the twin,
docs/commissioning.md.) Each
candidate's information is JᵀJ of its weighted, scaled Jacobian at the nominal parameters
(:mod:`planner.calibration.solve`); the design maximises log det of the information of the
identifiable directions (those of the *whole* candidate set; plus a unit prior, the tape
uncertainty, so the first picks are well defined): a greedy pass, then exchange passes that swap
a chosen pose for a candidate while log det grows.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from planner.calibration.measurements import MEASURED_COLUMNS
from planner.calibration.parameters import CalibrationError
from planner.calibration.parametric import POINT_ROWS, POSE_ROWS, ParametricModel
from planner.calibration.solve import identifiable_basis
from planner.model.exact_inverse import ExactInverse
from planner.model.types import CONTROLLED_POSE_NAMES, KinematicsError

__all__ = [
    "ApproachShortfall",
    "PoseDesign",
    "approach_shortfalls",
    "candidate_poses",
    "information_log_det",
    "measured_rows",
    "plan_poses",
]

_ANGLES = ("roll", "pitch", "yaw")
#: how far above the final approach's start the lower faces of the candidates stay [m, m, rad, rad] (round-off)
_APPROACH_ROOM = 1e-4


@dataclass(frozen=True)
class PoseDesign:
    """Chosen poses (N, 4: x, z, roll, pitch), their nominal actuators (N, 5), the log det of the design's
    information over the identifiable directions and how many directions that is (identifiable over the
    whole workspace, all candidates together). Of those, ``rank``: how many the chosen poses can separate
    at all (rank of their stacked Jacobian over the directions; below ``identifiable`` when too few poses
    are chosen, whatever is measured); ``determined``: how many they determine as well as a calibration
    from them asks (singular values of their weighted, scaled Jacobian ≥ ``min_singular``, the threshold
    :func:`~planner.calibration.solve.solve_calibration` applies); the others stay at nominal in such a
    calibration, and more poses determine more of them."""

    poses: np.ndarray
    actuators: np.ndarray
    log_det: float
    identifiable: int
    candidates: int
    rank: int
    determined: int


def measured_rows(points: bool = False, pose: bool = True) -> np.ndarray:
    """Output rows (:data:`~planner.calibration.parametric.OUTPUT_NAMES`) an instrument measures."""
    rows: list[int] = []
    if pose:
        rows += list(POSE_ROWS.values())
    if points:
        rows += [r + i for r in POINT_ROWS.values() for i in range(3)]
    return np.array(sorted(rows))


@dataclass(frozen=True)
class ApproachShortfall:
    """Pose ``row`` (0-based) reached from ``side`` has only ``room`` of the ``offset`` its final approach
    needs in DOF ``dof`` before a workspace face (the profile's offset less its lag) [m or rad]: its goto's
    approach is cut short there."""

    row: int
    dof: str
    side: str
    room: float
    offset: float


def approach_shortfalls(
    model: ParametricModel, poses: np.ndarray, sides: tuple[str, ...]
) -> tuple[ApproachShortfall, ...]:
    """Where gotos to ``poses`` (N, 4: x, z, roll, pitch) from each of ``sides`` (``"below"``, ``"above"``)
    find less room than the profile's ``motion.final_approach`` offset before the restricted workspace's face
    (the approach is then cut short and may not take the pin play up: such a row biases the fit; module
    docstring). Empty without a final approach or a workspace box."""
    hm = model.nominal_model
    approach, box = hm.profile.motion.final_approach, hm.workspace
    if approach is None or box is None:
        return ()
    lo = np.array([box[k][0] for k in CONTROLLED_POSE_NAMES])
    hi = np.array([box[k][1] for k in CONTROLLED_POSE_NAMES])
    offset = np.asarray(approach.offset())
    # with a lag the mechanism is aimed that far beyond the goal, the via with it: the approach needs the
    # offset less the lag before the face, from either side
    need = offset - np.asarray(approach.lag_vector())
    out = []
    for r, p in enumerate(np.asarray(poses, float).reshape(-1, 4)):
        for side in sides:
            room = p - lo if side == "below" else hi - p
            for k, name in enumerate(CONTROLLED_POSE_NAMES):
                if offset[k] > 0 and room[k] < need[k] - 1e-9:
                    out.append(ApproachShortfall(r, name, side, float(max(room[k], 0.0)), float(need[k])))
    return tuple(out)


def candidate_poses(
    model: ParametricModel,
    n: int = 300,
    *,
    seed: int = 0,
    margin: float = 0.02,
    random_only: bool = False,
    two_sided: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """(poses (M, 4), nominal actuators (M, 5)) inside the restricted workspace and the strokes: the box's
    corners, face centres and centre (2 % inside; the lower faces above the profile's final approach, the upper
    ones with its ``side = "above"``, both with ``two_sided``: each pose measured from both sides; module
    docstring), then ``n`` seeded random poses (``random_only``: those alone)."""
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 100_000:
        raise CalibrationError(f"n must be an integer in [1, 100000], got {n!r}")
    if not (isinstance(margin, (int, float)) and 0.0 <= margin < 0.5):
        raise CalibrationError(f"margin must be a number in [0, 0.5), got {margin!r}")
    hm = model.nominal_model
    box = hm.workspace
    if box is None:
        raise CalibrationError(
            f"profile {hm.profile.name} has no restricted workspace for category {hm.category}: no poses to plan"
        )
    lo = np.array([box[k][0] for k in CONTROLLED_POSE_NAMES])
    hi = np.array([box[k][1] for k in CONTROLLED_POSE_NAMES])
    shrink = 0.02 * (hi - lo)  # the box's corners are where limits meet: stay a little inside
    approach = hm.profile.motion.final_approach
    if two_sided and approach is None:
        raise CalibrationError(
            f"poses measured from both sides (--two-sided, --sides both) need the profile's motion.final_approach "
            f"(how far each side's approach starts), and {hm.profile.name} has none: add [motion.final_approach] "
            "(docs/commissioning.md) and give that profile with --profile"
        )
    room = shrink if approach is None else np.maximum(shrink, np.asarray(approach.offset()) + _APPROACH_ROOM)
    below = approach is not None and (two_sided or approach.side == "below")
    above = approach is not None and (two_sided or approach.side == "above")
    lo, hi = lo + (room if below else shrink), hi - (room if above else shrink)
    if np.any(lo >= hi):
        bad = [k for k, a, b in zip(CONTROLLED_POSE_NAMES, lo, hi, strict=True) if a >= b]
        raise CalibrationError(
            f"the restricted workspace of {hm.profile.name} is narrower in {', '.join(bad)} than the profile's "
            "motion.final_approach: no pose there is reached with its whole approach"
        )
    corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
    mid = (lo + hi) / 2
    faces = []
    for k in range(4):
        for v in (lo[k], hi[k]):
            f = mid.copy()
            f[k] = v
            faces.append(f)
    rng = np.random.default_rng(seed)
    samples = lo + (hi - lo) * rng.random((n, 4))
    cands = samples if random_only else np.vstack([corners, np.array(faces), mid[None, :], samples])
    inv = ExactInverse(hm)
    stroke = hm.upper - hm.lower
    q_lo, q_hi = hm.lower + margin * stroke, hm.upper - margin * stroke
    poses, acts = [], []
    for p in cands:
        try:
            q = inv.solve(p)[0]
        except KinematicsError:
            continue
        if np.all(q >= q_lo) and np.all(q <= q_hi):
            poses.append(p)
            acts.append(q)
    if not poses:
        raise CalibrationError("no candidate pose of the workspace is reachable within the strokes")
    return np.array(poses), np.array(acts)


def _informations(model: ParametricModel, actuators: np.ndarray, rows: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Weighted scaled Jacobians (M, len(rows), n) at the nominal parameters."""
    _, j = model.batch(actuators)
    assert j is not None
    w = 1.0 / sigma[rows]
    return j[:, rows, :] * w[None, :, None] * model.params.scale[None, None, :]


def information_log_det(js: np.ndarray, basis: np.ndarray, prior: float = 1.0) -> float:
    """log det(prior·I + Σ (J B)ᵀ(J B)) of per-pose Jacobians ``js`` (N, r, n) on the directions ``basis``."""
    jb = js @ basis
    info = prior * np.eye(basis.shape[1]) + np.einsum("kri,krj->ij", jb, jb)
    sign, ld = np.linalg.slogdet(info)
    return float(ld) if sign > 0 else -math.inf


def plan_poses(
    model: ParametricModel,
    n_poses: int,
    *,
    candidates: int = 300,
    seed: int = 0,
    points: bool = False,
    sigma_position_m: float = 0.001,
    sigma_angle_rad: float = 0.001,
    min_singular: float = 1.0,
    exchange_passes: int = 2,
    two_sided: bool = False,
) -> PoseDesign:
    """The ``n_poses`` poses to measure (D-optimal; module docstring). ``points``: the instrument also reads
    the marked points L, R, U. ``two_sided``: each pose will be measured from both sides (the candidates keep
    the final approach's room at both faces; the lag the two sides separate is not a design direction)."""
    if isinstance(n_poses, bool) or not isinstance(n_poses, int) or not 1 <= n_poses <= 1000:
        raise CalibrationError(f"n (poses to plan) must be an integer in [1, 1000], got {n_poses!r}")
    poses, acts = candidate_poses(model, candidates, seed=seed, two_sided=two_sided)
    if n_poses > poses.shape[0]:
        raise CalibrationError(
            f"n = {n_poses} poses asked, only {poses.shape[0]} candidates are reachable (the workspace box's corners "
            f"and face centres and {candidates} random poses): ask for fewer poses, or for more candidates "
            "(candidates, --candidates, up to 100000)"
        )
    sigma = np.array([sigma_angle_rad if c in _ANGLES else sigma_position_m for c in MEASURED_COLUMNS])
    rows = measured_rows(points=points)
    js = _informations(model, acts, rows, sigma)
    _, basis, _ = identifiable_basis(js.reshape(-1, js.shape[2]), min_singular)
    jb = js @ basis  # (M, r, k)
    k = basis.shape[1]
    per = np.einsum("mri,mrj->mij", jb, jb)  # (M, k, k)
    chosen: list[int] = []
    info = np.eye(k)
    for _ in range(n_poses):  # greedy: the candidate adding the most log det
        best, best_ld = -1, -math.inf
        for m in range(poses.shape[0]):
            if m in chosen:
                continue
            sign, ld = np.linalg.slogdet(info + per[m])
            if sign > 0 and ld > best_ld:
                best, best_ld = m, ld
        chosen.append(best)
        info = info + per[best]
    current = float(np.linalg.slogdet(info)[1])
    for _ in range(exchange_passes):  # exchange: swap a chosen pose for a better candidate
        improved = False
        for i in range(n_poses):
            base = info - per[chosen[i]]
            best, best_ld = chosen[i], current
            for m in range(poses.shape[0]):
                if m in chosen:
                    continue
                sign, ld = np.linalg.slogdet(base + per[m])
                if sign > 0 and ld > best_ld + 1e-9:
                    best, best_ld = m, ld
            if best != chosen[i]:
                chosen[i] = best
                info = base + per[best]
                current = best_ld
                improved = True
        if not improved:
            break
    idx = np.array(chosen)
    s = np.linalg.svd(jb[idx].reshape(-1, k), compute_uv=False)
    rank = int(np.count_nonzero(s > 1e-9 * s[0])) if s.size and s[0] > 0 else 0
    determined = int(np.count_nonzero(s >= min_singular))
    return PoseDesign(poses[idx], acts[idx], current, k, int(poses.shape[0]), rank, determined)
