"""Closed-form inverse kinematics of a 6R arm with a spherical wrist (arm thesis 2.36-2.71).

The arm is the anthropomorphic arm with spherical wrist of the source's Table 2.1, with an
optional base height ``d1`` and constant joint offsets (DH ``theta`` values)::

    link  a    alpha   d    theta
    1     0    π/2     d1   q1 + o1
    2     a2   0       0    q2 + o2
    3     0    π/2     0    q3 + o3
    4     0   -π/2     d4   q4 + o4
    5     0    π/2     0    q5 + o5
    6     0    0       d6   q6 + o6

plus any fixed base and tool transforms. The solution decouples position and orientation:

1. wrist centre ``p_w = p - d6 · z6`` (arm thesis 2.38-2.40 with the source's ``a3 = d4``);
2. elbow: ``cos β = (ρ² + z² - a2² - d4²) / (2 a2 d4)`` with ``β = θ3 - π/2`` (the source's
   ``θ3``), reachable only when ``|cos β| <= 1`` (arm thesis 2.42);
3. shoulder: ``θ1 = atan2(p_wy, p_wx)`` ("right", ν1,I) or that + π ("left", ν1,II) (arm
   thesis 2.56-2.57), ``θ2 = atan2(z, ρ) - atan2(d4 sin β, a2 + d4 cos β)`` with ``ρ`` signed
   by the shoulder side (a corrected form of arm thesis 2.49-2.55);
4. wrist: ``R36 = R03ᵀ R06 = rotz(θ4) roty(θ5) rotz(θ6)``, two ZYZ branches (arm thesis
   2.63-2.71).

Four arm postures × two wrist branches = eight solutions. Labels are geometric: the elbow is
"up" when it lies above the line from the shoulder to the wrist centre (the source ties
"elbow down" to ``ν3,I`` for both shoulder sides, which is geometric only for the right
shoulder). The target rotation given to :func:`solve_arm_ik` is projected onto SO(3) by
default; see ``docs/arm.md`` for the policy. Angles in radians, lengths in metres.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from planner.arm.dh import DHChain, check_joint_values, check_joint_vector, forward_kinematics, limit_violations
from planner.arm.transforms import (
    ArmInputError,
    check_rotation,
    homogeneous,
    invert_transform,
    nearest_rotation,
    orthonormality_defect,
    rotation_distance,
    solve_euler_zyz,
    wrap_angle,
)
from planner.errors import HitchInputError

__all__ = [
    "ArmStructureError",
    "UnreachableTargetError",
    "NoAdmissibleSolutionError",
    "SphericalWristArm",
    "ArmIKSolution",
    "ArmIKResult",
    "build_spherical_wrist_arm",
    "solve_arm_ik",
    "select_nearest_solution",
]

_HALF_PI = 0.5 * math.pi
#: Required (alpha) of the six links and which a / d must vanish.
_ALPHA = (_HALF_PI, 0.0, _HALF_PI, -_HALF_PI, _HALF_PI, 0.0)
_ZERO_A = (0, 2, 3, 4, 5)
_ZERO_D = (1, 2, 4)
#: Relative tolerance on |cos β| - 1 before a target counts as outside the workspace.
_REACH_TOL = 1e-12
#: Largest accepted ``rotation_tol`` of :func:`solve_arm_ik` (a defect of 0.1 is no rotation any more).
_MAX_ROTATION_TOL = 0.1
#: An unreachable target gets a "did you mean mm?" hint only beyond this many arm reaches.
_MM_HINT_FACTOR = 10.0
Shoulder = Literal["right", "left"]
Elbow = Literal["up", "down"]
Wrist = Literal["I", "II"]
#: Shoulder sides with the sign of the arm-plane distance ρ.
_SHOULDERS: tuple[tuple[Shoulder, float], ...] = (("right", 1.0), ("left", -1.0))
#: Elbow label of the two branches when the arm is stretched (sin β = 0).
_STRETCHED_ELBOW: tuple[Elbow, Elbow] = ("down", "up")
#: Wrist branch labels, in the order of :attr:`~planner.arm.transforms.ZYZSolution.branches`.
_WRISTS: tuple[Wrist, Wrist] = ("I", "II")


class ArmStructureError(HitchInputError):
    """The DH chain is not a 6R anthropomorphic arm with a spherical wrist."""


class UnreachableTargetError(HitchInputError):
    """The target pose is outside the arm's workspace; the message gives the reason."""


class NoAdmissibleSolutionError(HitchInputError):
    """Every analytic solution violates a joint limit; the message lists them."""


@dataclass(frozen=True, eq=False)
class SphericalWristArm:
    """The lengths [m] and joint offsets [rad] the closed form needs, and the chain itself."""

    chain: DHChain
    d1: float
    a2: float
    d4: float
    d6: float
    offsets: tuple[float, ...]


def build_spherical_wrist_arm(chain: DHChain, *, atol: float = 1e-9) -> SphericalWristArm:
    """Check that ``chain`` has the structure above (to ``atol``) and extract its parameters."""
    if chain.n != 6:
        raise ArmStructureError(f"chain: the closed form needs 6 joints, got {chain.n}")
    for i, link in enumerate(chain.links):
        where = f"links[{i}] ({link.name})"
        if link.kind != "revolute":
            raise ArmStructureError(f"{where}.kind = {link.kind!r}; required: 'revolute'")
        if abs(link.alpha - _ALPHA[i]) > atol:
            raise ArmStructureError(f"{where}.alpha = {link.alpha!r} rad; required: {_ALPHA[i]!r} (Table 2.1)")
        if i in _ZERO_A and abs(link.a) > atol:
            raise ArmStructureError(f"{where}.a = {link.a!r} m; required: 0 (Table 2.1)")
        if i in _ZERO_D and abs(link.d) > atol:
            raise ArmStructureError(f"{where}.d = {link.d!r} m; required: 0 (Table 2.1)")
    a2, d4 = chain.links[1].a, chain.links[3].d
    if not a2 > atol:
        raise ArmStructureError(f"links[1] ({chain.links[1].name}).a = {a2!r} m; required: > 0 (upper arm)")
    if not d4 > atol:
        raise ArmStructureError(f"links[3] ({chain.links[3].name}).d = {d4!r} m; required: > 0 (forearm)")
    return SphericalWristArm(
        chain=chain,
        d1=chain.links[0].d,
        a2=a2,
        d4=d4,
        d6=chain.links[5].d,
        offsets=tuple(link.theta for link in chain.links),
    )


@dataclass(frozen=True)
class ArmIKSolution:
    """One closed-form solution.

    Attributes:
        joints: Joint values ``q1..q6`` [rad]; inside the joint limits when ``within_limits``
            (the 2π-equivalent nearest the reference), else wrapped into ``(-pi, pi]``.
        shoulder: ``"right"`` (arm plane facing the wrist centre, ν1,I) or ``"left"`` (ν1,II).
        elbow: ``"up"`` / ``"down"``: elbow above / below the shoulder-wrist line.
        wrist: ``"I"`` (DH θ5 in ``[0, pi]``) or ``"II"`` (``[-pi, 0]``).
        within_limits: All six joints have a 2π-equivalent inside their limits.
        wrist_singular: ``sin θ5 ≈ 0``: θ4 was set from the reference, only θ4 ± θ6 matters.
        position_error: ``|p_fk - p_target|`` [m] (forward-kinematics check).
        rotation_error: Angle of ``R_targetᵀ R_fk`` [rad].
    """

    joints: tuple[float, ...]
    shoulder: Shoulder
    elbow: Elbow
    wrist: Wrist
    within_limits: bool
    wrist_singular: bool
    position_error: float
    rotation_error: float

    def as_array(self) -> np.ndarray:
        return np.array(self.joints)

    @property
    def fk_error(self) -> float:
        """``hypot(position_error [m], rotation_error [rad])``: one number for reports."""
        return math.hypot(self.position_error, self.rotation_error)

    @property
    def label(self) -> str:
        return f"{self.shoulder}/{self.elbow}/{self.wrist}"


@dataclass(frozen=True, eq=False)
class ArmIKResult:
    """All closed-form solutions for one target pose.

    Attributes:
        position: Target tool position in the world frame [m].
        rotation: Target tool rotation actually solved for (the SO(3) projection of the given
            matrix unless ``orthonormalize=False``).
        rotation_defect: ``max |RᵀR - I|`` of the rotation as given.
        projection_change: ``max |R_projected - R_given|`` (0 when not projected).
        wrist_centre: Wrist centre in the world frame [m].
        solutions: Up to eight solutions; empty when unreachable.
        reachable: ``False`` when no solution exists; ``reason`` says why.
        reason: Empty when reachable.
        cos_elbow: ``cos β`` of arm thesis 2.42 (``|cos β| > 1`` means unreachable).
        shoulder_singular: Wrist centre on the first joint axis: θ1 taken from the reference.
        elbow_singular: Arm fully stretched or folded: the two elbow solutions coincide.
    """

    position: np.ndarray
    rotation: np.ndarray
    rotation_defect: float
    projection_change: float
    wrist_centre: np.ndarray
    solutions: tuple[ArmIKSolution, ...]
    reachable: bool
    reason: str
    cos_elbow: float
    shoulder_singular: bool
    elbow_singular: bool

    @property
    def admissible(self) -> tuple[ArmIKSolution, ...]:
        """The solutions within the joint limits."""
        return tuple(s for s in self.solutions if s.within_limits)


def _vec3(value, name: str) -> np.ndarray:
    try:
        v = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ArmInputError(f"{name} must be 3 numbers [m], got {value!r}") from None
    if v.size != 3 or not np.all(np.isfinite(v)):
        raise ArmInputError(f"{name} must be 3 finite numbers (x, y, z) [m], got {v.tolist()}")
    return v


def _fit_joint(angle: float, lower: float, upper: float, reference: float) -> float | None:
    """The 2π-equivalent of ``angle`` inside ``[lower, upper]`` nearest ``reference``, or None."""
    best = None
    for k in range(-2, 3):
        x = angle + 2.0 * math.pi * k
        if lower - 1e-12 <= x <= upper + 1e-12:
            x = min(max(x, lower), upper)
            if best is None or abs(x - reference) < abs(best - reference):
                best = x
    return best


def _fit_joints(chain: DHChain, q: Sequence[float], reference: np.ndarray) -> tuple[tuple[float, ...], bool]:
    """Each joint's 2π-equivalent inside its limits nearest ``reference``, and True; or ``q``
    unchanged and False when some joint has none."""
    fitted: list[float] = []
    for x, link, r in zip(q, chain.links, reference, strict=True):
        f = _fit_joint(x, link.lower, link.upper, r)
        if f is None:
            return tuple(float(v) for v in q), False
        fitted.append(f)
    return tuple(float(x) for x in fitted), True


def _rotation_tol(value) -> float:
    """``rotation_tol`` of :func:`solve_arm_ik` checked: a finite number in ``(0, 0.1]``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ArmInputError(f"rotation_tol must be a number, got {type(value).__name__} {value!r}")
    v = float(value)
    if not (math.isfinite(v) and 0.0 < v <= _MAX_ROTATION_TOL):
        raise ArmInputError(f"rotation_tol = {v} is outside the allowed (0, {_MAX_ROTATION_TOL:g}]")
    return v


def _wrist_centre(arm: SphericalWristArm, p: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``(R06, p_w, cos β)`` of the tool pose ``(p [m], R)``: the DH part's target rotation, the wrist
    centre in frame 0 [m] and the elbow cosine of arm thesis 2.42 (``|cos β| > 1``: unreachable)."""
    chain = arm.chain
    # Target of the DH part: T06 = base⁻¹ · T · tool⁻¹ (tool and base are rigid).
    T06 = invert_transform(chain.base) @ homogeneous(R, p) @ invert_transform(chain.tool)
    R06 = T06[:3, :3]
    pw0 = T06[:3, 3] - arm.d6 * R06[:, 2]  # wrist centre in frame 0 (arm thesis 2.38-2.40)
    x, y, z = pw0[0], pw0[1], pw0[2] - arm.d1
    a2, d4 = arm.a2, arm.d4
    c = (x * x + y * y + z * z - a2 * a2 - d4 * d4) / (2.0 * a2 * d4)  # arm thesis 2.42
    return R06, pw0, float(c)


def _mm_hint(arm: SphericalWristArm, p: np.ndarray, R: np.ndarray, distance: float) -> str:
    """``"; did you mean mm? …"`` when the unreachable position ``p`` read as millimetres is
    reachable (typed in mm, the wrist centre lands ~1000 times too far), else ``""``. Only for a
    wrist centre more than :data:`_MM_HINT_FACTOR` reaches away (``distance`` [m] from the
    shoulder): a near miss in metres is no unit slip."""
    if float(np.max(np.abs(p))) < 1.0 or distance <= _MM_HINT_FACTOR * (arm.a2 + arm.d4):
        return ""  # as planner.errors.unit_hint: no hint for values below 1
    p_m = p / 1000.0
    if abs(_wrist_centre(arm, p_m, R)[2]) > 1.0 + _REACH_TOL:
        return ""
    shown = ", ".join(f"{v:.6g}" for v in p.tolist())
    return f"; did you mean mm? position ({shown}) mm = ({', '.join(f'{v:.6g}' for v in p_m.tolist())}) m is reachable"


def solve_arm_ik(
    arm: SphericalWristArm,
    position,
    rotation,
    *,
    reference=None,
    orthonormalize: bool = True,
    rotation_tol: float = 1e-3,
) -> ArmIKResult:
    """All closed-form solutions for the tool pose ``(position [m], rotation)`` in the world frame.

    Args:
        arm: From :func:`build_spherical_wrist_arm`.
        position: Target tool position (3,) [m].
        rotation: Target tool orientation (3x3, or 9 values row-major). Its orthonormality
            defect ``max |RᵀR - I|`` must be at most ``rotation_tol``.
        reference: Joint vector (6,) [rad] that fixes θ1 at a shoulder singularity, θ4 at a
            wrist singularity and which 2π-equivalent is reported (default zeros).
        orthonormalize: Solve for the nearest rotation (SVD) instead of the matrix as given.
            With ``False`` the textbook formulas are applied to the given entries, as the
            source does with its 4-decimal matrix; the forward-kinematics error then reflects
            the matrix's own defect.
        rotation_tol: Accepted orthonormality defect of ``rotation``, ``0 < rotation_tol <= 0.1``
            (default 1e-3, enough for matrices printed to four decimals).

    An unreachable target gives ``reachable=False`` with a ``reason`` and no solutions; when the
    position read as millimetres would be reachable, the reason ends "did you mean mm?". A
    reference beyond ±2π (degrees) raises :class:`ArmInputError`.
    """
    chain = arm.chain
    p = _vec3(position, "position")
    tol = _rotation_tol(rotation_tol)
    R_in = check_rotation(rotation, "rotation", atol=tol)
    ref = np.zeros(6) if reference is None else check_joint_values(chain, reference, "reference")
    defect = orthonormality_defect(R_in)
    R = nearest_rotation(R_in) if orthonormalize else R_in
    change = float(np.max(np.abs(R - R_in))) if orthonormalize else 0.0

    R06, pw0, c = _wrist_centre(arm, p, R)
    wc = (chain.base @ np.append(pw0, 1.0))[:3]
    x, y, z = pw0[0], pw0[1], pw0[2] - arm.d1
    a2, d4, off = arm.a2, arm.d4, arm.offsets
    rho0 = math.hypot(x, y)

    for arr in (p, R, wc):
        arr.setflags(write=False)

    def result(solutions, reachable, reason, shoulder_singular=False, elbow_singular=False):
        return ArmIKResult(
            position=p,
            rotation=R,
            rotation_defect=defect,
            projection_change=change,
            wrist_centre=wc,
            solutions=tuple(solutions),
            reachable=reachable,
            reason=reason,
            cos_elbow=float(c),
            shoulder_singular=shoulder_singular,
            elbow_singular=elbow_singular,
        )

    if abs(c) > 1.0 + _REACH_TOL:
        dist = math.hypot(rho0, z)
        side = "too far from" if c > 0 else "too close to"
        reason = (
            f"target unreachable: the wrist centre ({wc[0]:.6g}, {wc[1]:.6g}, {wc[2]:.6g}) m is {dist:.6g} m from the "
            f"shoulder, {side} it; reachable distances are [{abs(a2 - d4):.6g}, {a2 + d4:.6g}] m "
            f"(elbow cos β = {c:.6g}, allowed [-1, 1])"
        ) + _mm_hint(arm, p, R, dist)
        return result((), False, reason)
    c = min(1.0, max(-1.0, c))
    s_abs = math.sqrt(max(0.0, 1.0 - c * c))
    elbow_singular = s_abs <= 1e-6  # beta within 1e-6 rad of 0 or pi (c carries ~eps, s ~sqrt(eps))
    scale = max(a2 + d4, 1.0)
    shoulder_singular = rho0 <= 1e-12 * scale
    theta1 = (ref[0] + off[0]) if shoulder_singular else math.atan2(y, x)

    solutions = []
    for shoulder, sigma in _SHOULDERS:
        t1 = theta1 if sigma > 0 else theta1 + math.pi
        rho = sigma * rho0
        for branch, sb in enumerate((s_abs, -s_abs)):
            beta = math.atan2(sb, c)
            t2 = math.atan2(z, rho) - math.atan2(d4 * sb, a2 + d4 * c)
            t3 = beta + _HALF_PI
            # Elbow above the shoulder-wrist line <=> sigma * sin(beta) < 0 (stretched: by branch).
            elbow: Elbow = ("up" if sigma * sb < 0 else "down") if sb != 0.0 else _STRETCHED_ELBOW[branch]
            R03 = (
                chain.links[0].transform(t1 - off[0])
                @ chain.links[1].transform(t2 - off[1])
                @ chain.links[2].transform(t3 - off[2])
            )[:3, :3]
            zyz = solve_euler_zyz(R03.T @ R06, reference_phi=ref[3] + off[3], atol=max(tol, 1e-9))
            for wrist, angles in zip(_WRISTS, zyz.branches, strict=False):  # one branch when wrist-singular
                theta = (t1, t2, t3, angles.phi, angles.theta, angles.psi)
                q = [wrap_angle(th - o) for th, o in zip(theta, off, strict=True)]
                joints, ok = _fit_joints(chain, q, ref)
                frames = forward_kinematics(chain, joints)
                solutions.append(
                    ArmIKSolution(
                        joints=joints,
                        shoulder=shoulder,
                        elbow=elbow,
                        wrist=wrist,
                        within_limits=ok,
                        wrist_singular=zyz.singular,
                        position_error=float(np.linalg.norm(frames.position - p)),
                        rotation_error=rotation_distance(R, frames.rotation),
                    )
                )
    return result(solutions, True, "", shoulder_singular, elbow_singular)


def select_nearest_solution(
    arm: SphericalWristArm,
    result: ArmIKResult,
    reference,
    *,
    weights=None,
) -> ArmIKSolution:
    """The admissible solution nearest ``reference`` (6,) [rad, each within ±2π] in the weighted joint distance.

    Each joint is first moved to its 2π-equivalent inside the limits nearest the reference;
    the returned solution carries those values. ``weights`` (6,) >= 0 default to ones.
    Raises :class:`UnreachableTargetError` when the target is unreachable and
    :class:`NoAdmissibleSolutionError` when every solution violates a joint limit.
    """
    chain = arm.chain
    ref = check_joint_values(chain, reference, "reference")
    w = np.ones(6) if weights is None else check_joint_vector(chain, weights, "weights")
    if np.any(w < 0):
        raise ArmInputError(f"weights must be >= 0, got {w.tolist()}")
    if not result.reachable:
        raise UnreachableTargetError(result.reason)
    best, best_cost = None, math.inf
    for sol in result.solutions:
        joints, ok = _fit_joints(chain, sol.joints, ref)
        if not ok:
            continue
        cost = float(np.sum(w * (np.array(joints) - ref) ** 2))
        if cost < best_cost:
            best, best_cost = dataclasses.replace(sol, joints=joints), cost
    if best is None:
        details = "; ".join(f"{s.label}: {', '.join(limit_violations(chain, s.joints))}" for s in result.solutions)
        raise NoAdmissibleSolutionError(f"no analytic solution within the joint limits ({details})")
    return best
