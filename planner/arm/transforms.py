"""Rotations and homogeneous transforms: elementary rotations, ZYZ Euler angles, SE(3) helpers.

Conventions (those of the serial-arm source, a Tampere bachelor's thesis, see ``docs/arm.md``;
equation numbers are written ``(arm thesis 2.7)``):

* A rotation matrix holds the axes of the moving frame as *columns*, expressed in the
  reference frame (arm thesis 2.6). Post-multiplying rotates about the moving frame's own
  axes, pre-multiplying about the reference frame's axes.
* Elementary rotations ``rotx``, ``roty``, ``rotz`` rotate positively (right-hand rule) about
  the named axis (arm thesis 2.7-2.9).
* ZYZ Euler angles ``(phi, theta, psi)`` mean ``R = rotz(phi) @ roty(theta) @ rotz(psi)``
  (arm thesis 2.10). Branch I has ``theta`` in ``(0, pi)``, branch II in ``(-pi, 0)``; both
  give the same matrix (arm thesis 2.65-2.70, with the sign typo of 2.68 corrected).
* A homogeneous transform is ``[[R, p], [0, 0, 0, 1]]`` (arm thesis 2.11).

Angles are in radians, lengths in metres. Functions with the ``_ca`` suffix build CasADi
expressions (SX or MX) for use inside symbolic models.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from planner.errors import HitchInputError

__all__ = [
    "ArmInputError",
    "RotationMatrixError",
    "rotx",
    "roty",
    "rotz",
    "rotx_ca",
    "roty_ca",
    "rotz_ca",
    "homogeneous",
    "homogeneous_ca",
    "translation",
    "invert_transform",
    "wrap_angle",
    "skew",
    "vee",
    "so3_log",
    "rotation_distance",
    "orthonormality_defect",
    "nearest_rotation",
    "check_rotation",
    "check_transform",
    "EulerZYZ",
    "ZYZSolution",
    "euler_zyz_matrix",
    "solve_euler_zyz",
]

#: Below this sin(theta) the remaining angle psi is recomputed from the full matrix so the
#: round trip stays exact near the ZYZ singularity (textbook formulas lose eps/sin(theta)).
_NEAR_SINGULAR = 1e-4


class ArmInputError(HitchInputError):
    """A malformed argument to the serial-arm code (not a number, wrong size, not finite, out of
    range); the message names the field and what is allowed."""


class RotationMatrixError(HitchInputError):
    """A matrix that should be a rotation (or a homogeneous transform) is not one."""


def _angle(value, name: str) -> float:
    try:
        a = float(value)
    except (TypeError, ValueError):
        raise ArmInputError(f"{name} must be a number [rad], got {value!r}") from None
    if not math.isfinite(a):
        raise ArmInputError(f"{name} must be a finite angle [rad], got {a}")
    return a


def rotx(angle: float) -> np.ndarray:
    """Rotation by ``angle`` [rad] about the x axis (arm thesis 2.9)."""
    a = _angle(angle, "angle")
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def roty(angle: float) -> np.ndarray:
    """Rotation by ``angle`` [rad] about the y axis (arm thesis 2.8)."""
    a = _angle(angle, "angle")
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotz(angle: float) -> np.ndarray:
    """Rotation by ``angle`` [rad] about the z axis (arm thesis 2.7)."""
    a = _angle(angle, "angle")
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotx_ca(angle):
    """CasADi version of :func:`rotx` (``angle`` is an SX/MX scalar or a number)."""
    c, s = ca.cos(angle), ca.sin(angle)
    return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))


def roty_ca(angle):
    """CasADi version of :func:`roty`."""
    c, s = ca.cos(angle), ca.sin(angle)
    return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))


def rotz_ca(angle):
    """CasADi version of :func:`rotz`."""
    c, s = ca.cos(angle), ca.sin(angle)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def _vector3(value, name: str) -> np.ndarray:
    try:
        v = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ArmInputError(f"{name} must be 3 numbers [m], got {value!r}") from None
    if v.size != 3:
        raise ArmInputError(f"{name} must have 3 components (x, y, z) [m], got {v.size}")
    if not np.all(np.isfinite(v)):
        raise ArmInputError(f"{name} must be finite, got {v.tolist()}")
    return v


def _matrix3(value, name: str) -> np.ndarray:
    try:
        m = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise RotationMatrixError(f"{name} must be a 3x3 matrix of numbers, got {value!r}") from None
    if m.size == 9:
        m = m.reshape(3, 3)
    if m.shape != (3, 3):
        raise RotationMatrixError(f"{name} must be a 3x3 matrix (or 9 values, row-major), got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise RotationMatrixError(f"{name} must be finite, got {m.tolist()}")
    return m


def homogeneous(rotation=None, position=None) -> np.ndarray:
    """The 4x4 transform ``[[R, p], [0, 0, 0, 1]]`` (arm thesis 2.11).

    ``rotation`` defaults to the identity, ``position`` [m] to the origin. The rotation is
    taken as given (validate it with :func:`check_rotation` when it comes from outside).
    """
    T = np.eye(4)
    if rotation is not None:
        T[:3, :3] = _matrix3(rotation, "rotation")
    if position is not None:
        T[:3, 3] = _vector3(position, "position")
    return T


def homogeneous_ca(rotation, position):
    """CasADi version of :func:`homogeneous` (3x3 rotation, 3-vector position)."""
    return ca.vertcat(ca.horzcat(rotation, ca.reshape(position, 3, 1)), ca.horzcat(0, 0, 0, 1))


def translation(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    """Pure translation [m] as a homogeneous transform (arm thesis 2.15)."""
    return homogeneous(position=(x, y, z))


def invert_transform(T) -> np.ndarray:
    """Inverse of a rigid transform: ``[[Rᵀ, -Rᵀ p], [0, 1]]`` (exact, no matrix inversion)."""
    T = check_transform(T, "transform", atol=1e-6)
    R, p = T[:3, :3], T[:3, 3]
    return homogeneous(R.T, -R.T @ p)


def wrap_angle(angle):
    """Wrap angle(s) [rad] into ``(-pi, pi]`` (scalars or arrays)."""
    if isinstance(angle, (float, int)):
        return math.pi - (math.pi - float(angle)) % (2.0 * math.pi)
    a = np.asarray(angle, dtype=float)
    w = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return float(w) if w.ndim == 0 else w


def skew(v) -> np.ndarray:
    """The cross-product matrix ``[v]x`` with ``skew(v) @ w == cross(v, w)``."""
    x, y, z = _vector3(v, "v")
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def vee(S) -> np.ndarray:
    """Inverse of :func:`skew` for the skew-symmetric part of ``S``."""
    S = np.asarray(S, dtype=float)
    return 0.5 * np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]])


def so3_log(R) -> np.ndarray:
    """Rotation vector ``w`` [rad] with ``R = exp([w]x)``; ``|w|`` in ``[0, pi]``.

    Uses ``atan2(|vee(R - Rᵀ)| / 2, (tr R - 1) / 2)`` for the angle, which is accurate for
    small angles (``arccos`` of the trace loses half the digits there), and the symmetric
    part near ``pi``.
    """
    R = _matrix3(R, "R")
    v = vee(R)  # = sin(angle) * axis
    s = float(np.linalg.norm(v))
    c = 0.5 * (float(np.trace(R)) - 1.0)
    angle = math.atan2(s, c)
    if angle < 1e-8:
        return v  # first order: sin(angle) ~ angle
    if angle < math.pi - 1e-4:
        return v * (angle / s)
    # Near pi: axis from the symmetric part R + Rᵀ = 2 cos I + 2 (1 - cos) a aᵀ.
    B = 0.5 * (R + R.T) - c * np.eye(3)
    k = int(np.argmax(np.diag(B)))
    axis = B[:, k] / math.sqrt(max(B[k, k], 1e-300))
    axis /= np.linalg.norm(axis)
    if float(axis @ v) < 0.0:
        axis = -axis
    return axis * angle


def rotation_distance(A, B) -> float:
    """Geodesic distance [rad] between two rotations: the angle of ``Aᵀ B``."""
    A, B = _matrix3(A, "A"), _matrix3(B, "B")
    return float(np.linalg.norm(so3_log(A.T @ B)))


def orthonormality_defect(R) -> float:
    """``max |RᵀR - I|`` (elementwise), or ``inf`` when ``det R <= 0``."""
    R = _matrix3(R, "R")
    if np.linalg.det(R) <= 0.0:
        return math.inf
    return float(np.max(np.abs(R.T @ R - np.eye(3))))


def nearest_rotation(M) -> np.ndarray:
    """The rotation nearest to ``M`` in the Frobenius norm (polar factor via SVD, det +1)."""
    M = _matrix3(M, "M")
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)) or 1.0)])
    return U @ D @ Vt


def check_rotation(R, name: str = "rotation", *, atol: float = 1e-9) -> np.ndarray:
    """Validate a rotation matrix: 3x3, finite, ``max |RᵀR - I| <= atol`` and ``det > 0``.

    Returns a float copy. Raises :class:`RotationMatrixError` naming ``name``, the measured
    defect and the allowed tolerance.
    """
    R = _matrix3(R, name)
    defect = orthonormality_defect(R)
    if not defect <= atol:
        what = "has det <= 0 (a reflection or singular)" if math.isinf(defect) else f"has max|RᵀR - I| = {defect:.3g}"
        raise RotationMatrixError(  # the bound names its quantity: "allowed: <= 0.001 with det > 0" did not
            f"{name} is not a rotation matrix: it {what}; allowed: <= {atol:g} for max|RᵀR - I| "
            "(elementwise), with det(R) > 0"
        )
    return R


def check_transform(T, name: str = "transform", *, atol: float = 1e-9) -> np.ndarray:
    """Validate a 4x4 rigid transform (rotation block checked like :func:`check_rotation`)."""
    try:
        T = np.array(T, dtype=float)
    except (TypeError, ValueError):
        raise RotationMatrixError(f"{name} must be a 4x4 matrix of numbers, got {T!r}") from None
    if T.shape != (4, 4):
        raise RotationMatrixError(f"{name} must be a 4x4 homogeneous transform, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise RotationMatrixError(f"{name} must be finite")
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise RotationMatrixError(f"{name}: last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    check_rotation(T[:3, :3], f"{name} rotation block", atol=atol)
    return T


@dataclass(frozen=True)
class EulerZYZ:
    """ZYZ Euler angles [rad]: ``R = rotz(phi) @ roty(theta) @ rotz(psi)`` (arm thesis 2.10)."""

    phi: float
    theta: float
    psi: float

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.phi, self.theta, self.psi)

    def matrix(self) -> np.ndarray:
        return euler_zyz_matrix(self.phi, self.theta, self.psi)


@dataclass(frozen=True)
class ZYZSolution:
    """Result of :func:`solve_euler_zyz`.

    Attributes:
        branches: ``(branch I, branch II)`` normally; one entry when ``singular``.
        singular: ``sin(theta)`` was at most the singular tolerance: ``theta`` is exactly 0 or
            ``pi``, only ``phi + psi`` (``theta = 0``) or ``phi - psi`` (``theta = pi``) is
            defined, ``phi`` was set to the requested reference.
        sin_theta: ``|sin(theta)| = sqrt(r13² + r23²)`` of the input.
    """

    branches: tuple[EulerZYZ, ...]
    singular: bool
    sin_theta: float


def euler_zyz_matrix(phi: float, theta: float, psi: float) -> np.ndarray:
    """``rotz(phi) @ roty(theta) @ rotz(psi)`` (arm thesis 2.10)."""
    return rotz(phi) @ roty(theta) @ rotz(psi)


def _psi_consistent(R: np.ndarray, phi: float, theta: float) -> float:
    # rotz(psi) = (rotz(phi) roty(theta))ᵀ R: exact for a rotation whatever the error of phi.
    M = (rotz(phi) @ roty(theta)).T @ R
    return math.atan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1])


def solve_euler_zyz(
    R,
    *,
    reference_phi: float = 0.0,
    singular_tol: float = 1e-10,
    atol: float = 1e-9,
) -> ZYZSolution:
    """Both ZYZ angle sets of a rotation matrix (arm thesis 2.65-2.70).

    Branch I (``theta`` in ``[0, pi]``)::

        phi = atan2(r23, r13), theta = atan2(sqrt(r13² + r23²), r33), psi = atan2(r32, -r31)

    Branch II (``theta`` in ``[-pi, 0]``)::

        phi = atan2(-r23, -r13), theta = atan2(-sqrt(r13² + r23²), r33), psi = atan2(-r32, r31)

    (the source prints ``atan2(-r23, r13)`` in 2.68; its Matlab listing, figure 3.4, has the
    correct ``atan2(-r23, -r13)``). All angles are wrapped into ``(-pi, pi]``.

    Singular case ``sqrt(r13² + r23²) <= singular_tol``: ``theta`` is exactly 0 (``r33 > 0``) or
    ``pi``, ``phi = reference_phi`` and ``psi`` follows from the rest of the matrix; a single branch
    is returned. Its round trip drops the residual tilt: ``euler_zyz_matrix(*angles)`` differs
    from ``R`` by at most ``sqrt(r13² + r23²) <= singular_tol`` per entry (plus rounding; exact
    for an exactly singular matrix). Close to the singularity
    (``sin(theta) < 1e-4``) ``psi`` is taken from the full matrix as well, which keeps
    ``euler_zyz_matrix(*angles) == R`` to rounding error.

    ``atol`` is the accepted orthonormality defect of ``R`` (raise it to apply the formulas to
    a rounded, slightly non-orthonormal matrix the way the source does).
    """
    R = check_rotation(R, "R", atol=atol)
    ref = _angle(reference_phi, "reference_phi")
    if not (0.0 <= singular_tol < 1.0):
        raise ArmInputError(f"singular_tol must lie in [0, 1), got {singular_tol}")
    r13, r23, r33 = R[0, 2], R[1, 2], R[2, 2]
    st = math.hypot(r13, r23)
    if st <= singular_tol:
        # Exactly 0 or π, as documented: with phi fixed at the reference, the tilt atan2(st, r33)
        # would point in the reference's direction, not the matrix's, and double the error.
        theta = 0.0 if r33 > 0.0 else math.pi
        phi = wrap_angle(ref)
        psi = wrap_angle(_psi_consistent(R, phi, theta))
        return ZYZSolution((EulerZYZ(phi, theta, psi),), True, st)
    theta = math.atan2(st, r33)
    if st < _NEAR_SINGULAR:
        phi = math.atan2(r23, r13)
        psi = _psi_consistent(R, phi, theta)
        first = EulerZYZ(phi, theta, psi)
        second = EulerZYZ(wrap_angle(phi + math.pi), -theta, wrap_angle(psi + math.pi))
        return ZYZSolution((first, second), False, st)
    first = EulerZYZ(math.atan2(r23, r13), theta, math.atan2(R[2, 1], -R[2, 0]))
    second = EulerZYZ(math.atan2(-r23, -r13), math.atan2(-st, r33), math.atan2(-R[2, 1], R[2, 0]))
    return ZYZSolution((first, second), False, st)
