"""Denavit-Hartenberg chains: a table of (a, alpha, d, theta), forward kinematics, Jacobians.

Standard (distal) DH convention, as in the serial-arm source (arm thesis 2.17-2.19, Table
2.1): the transform from frame ``i-1`` to frame ``i`` is ::

    A_i = rotz(theta_i) · transz(d_i) · transx(a_i) · rotx(alpha_i)

        = [[cθ, -sθ cα,  sθ sα, a cθ],
           [sθ,  cθ cα, -cθ sα, a sθ],
           [ 0,     sα,     cα,    d],
           [ 0,      0,      0,    1]]

(the source's typeset 2.19 has four wrong entries, see ``docs/arm.md``). Joint ``i`` moves
about / along ``z_{i-1}``: a revolute joint adds its variable to ``theta_i`` (the table value
is a constant offset), a prismatic joint adds it to ``d_i``. The chain is
``T = base · A_1 · ... · A_n · tool`` (arm thesis 2.16).

Units: a, d and prismatic variables in metres; alpha, theta and revolute variables in
radians. :func:`build_casadi_chain` gives the same model as CasADi functions
``q -> (p, R)`` and ``q -> J`` for the optimisation-based IK.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import casadi as ca
import numpy as np

from planner.arm.transforms import ArmInputError, check_transform, homogeneous_ca, rotx_ca, rotz_ca
from planner.errors import HitchInputError, unit_hint

__all__ = [
    "JointKind",
    "JointLimitError",
    "DHLink",
    "DHChain",
    "ChainFrames",
    "CasadiChain",
    "dh_transform",
    "dh_transform_ca",
    "build_dh_chain",
    "forward_kinematics",
    "geometric_jacobian",
    "check_joint_vector",
    "check_joint_values",
    "limit_violations",
    "build_casadi_chain",
    "MAX_LENGTH",
    "MAX_REVOLUTE",
]

JointKind = Literal["revolute", "prismatic"]
_KINDS = ("revolute", "prismatic")
#: Revolute joint limits, and so every meaningful revolute joint value, lie within ±2π [rad].
MAX_REVOLUTE = 2.0 * math.pi
#: Link lengths ``a``, offsets ``d`` and prismatic joint limits lie within ±10 m [m]: no serial
#: arm of this product comes near it, and a length typed in millimetres (a2 = 100) exceeds it
#: (the error then asks "did you mean mm?").
MAX_LENGTH = 10.0
#: Slack [rad or m] on the ±MAX bounds of joint values (a limit of exactly 2π plus rounding).
_VALUE_SLACK = 1e-9


class JointLimitError(HitchInputError):
    """A joint vector outside the chain's joint limits; the message names joint, value, range."""


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class DHLink:
    """One row of a DH table plus its joint.

    Attributes:
        a: Link length along ``x_i`` [m].
        alpha: Link twist about ``x_i`` [rad].
        d: Offset along ``z_{i-1}`` [m]; for a prismatic joint the joint variable is added.
        theta: Angle about ``z_{i-1}`` [rad]; for a revolute joint the joint variable is added
            (so this is the joint's zero offset).
        kind: ``"revolute"`` or ``"prismatic"``.
        lower, upper: Joint limits of the joint variable [rad or m], ``lower < upper``.
        name: Label used in messages (default ``"joint<i>"``).
    """

    a: float
    alpha: float
    d: float
    theta: float
    kind: JointKind = "revolute"
    lower: float = -math.pi
    upper: float = math.pi
    name: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str):
            raise ArmInputError(
                f"name must be a string (the joint's label), got {type(self.name).__name__} {self.name!r}"
            )
        label = self.name or "link"
        for f in ("a", "alpha", "d", "theta", "lower", "upper"):
            v = getattr(self, f)
            if isinstance(v, (bool, str, bytes)):  # float(True) == 1.0, float("0.1") == 0.1: not numbers here
                raise ArmInputError(f"{label}.{f} must be a number, got {type(v).__name__} {v!r}")
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise ArmInputError(f"{label}.{f} must be a number, got {v!r}") from None
            if not math.isfinite(v):
                raise ArmInputError(f"{label}.{f} must be finite, got {v}")
            object.__setattr__(self, f, v)
        if self.kind not in _KINDS:
            raise ArmInputError(f"{label}.kind must be one of {_KINDS}, got {self.kind!r}")
        for f in ("a", "d"):
            v = getattr(self, f)
            if abs(v) > MAX_LENGTH:
                raise ArmInputError(
                    f"{label}.{f} = {v:.6g} m is outside the allowed [-{MAX_LENGTH:g}, {MAX_LENGTH:g}] m"
                    + unit_hint(v, -MAX_LENGTH, MAX_LENGTH, "m")
                )
        for f in ("alpha", "theta"):
            v = getattr(self, f)
            if abs(v) > MAX_REVOLUTE:
                raise ArmInputError(
                    f"{label}.{f} = {v:.6g} rad is outside the allowed ±2π rad"
                    + unit_hint(v, -MAX_REVOLUTE, MAX_REVOLUTE, "rad")
                )
        if not self.lower < self.upper:
            raise ArmInputError(f"{label}: joint limits need lower < upper, got [{self.lower}, {self.upper}]")
        bound = MAX_REVOLUTE if self.kind == "revolute" else MAX_LENGTH
        unit = "rad" if self.kind == "revolute" else "m"
        for f in ("lower", "upper"):
            v = getattr(self, f)
            if abs(v) > bound:
                raise ArmInputError(
                    f"{label}.{f} = {v:.6g} {unit} is outside the allowed ±{bound:.6g} {unit} for a {self.kind} joint"
                    + unit_hint(v, -bound, bound, unit)
                )

    def parameters(self, q: float) -> tuple[float, float, float, float]:
        """``(a, alpha, d, theta)`` with the joint variable ``q`` applied."""
        if self.kind == "revolute":
            return self.a, self.alpha, self.d, self.theta + q
        return self.a, self.alpha, self.d + q, self.theta

    def transform(self, q: float) -> np.ndarray:
        """``A_i(q)`` (4x4) for this link."""
        return dh_transform(*self.parameters(q))


def dh_transform(a: float, alpha: float, d: float, theta: float) -> np.ndarray:
    """The DH link transform ``rotz(theta) transz(d) transx(a) rotx(alpha)`` (arm thesis 2.19, corrected)."""
    ct, st, ca_, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array(
        [
            [ct, -st * ca_, st * sa, a * ct],
            [st, ct * ca_, -ct * sa, a * st],
            [0.0, sa, ca_, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def dh_transform_ca(a, alpha, d, theta):
    """CasADi version of :func:`dh_transform` (any argument may be symbolic)."""
    R = rotz_ca(theta) @ rotx_ca(alpha)
    p = ca.vertcat(a * ca.cos(theta), a * ca.sin(theta), d)
    return homogeneous_ca(R, p)


@dataclass(frozen=True, eq=False)
class DHChain:
    """A serial chain: DH links between a fixed base transform and a fixed tool transform.

    Build with :func:`build_dh_chain`. ``base`` maps the chain's frame 0 into the world frame,
    ``tool`` maps the tool frame into frame ``n``; both are read-only 4x4 arrays.
    """

    links: tuple[DHLink, ...]
    base: np.ndarray = field(default_factory=lambda: _readonly(np.eye(4)))
    tool: np.ndarray = field(default_factory=lambda: _readonly(np.eye(4)))

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.links)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(link.name for link in self.links)

    @property
    def lower(self) -> np.ndarray:
        return np.array([link.lower for link in self.links])

    @property
    def upper(self) -> np.ndarray:
        return np.array([link.upper for link in self.links])

    @property
    def kinds(self) -> tuple[JointKind, ...]:
        return tuple(link.kind for link in self.links)


def build_dh_chain(links: Sequence[DHLink], *, base=None, tool=None) -> DHChain:
    """Validate and build a :class:`DHChain`.

    Links without a name are named ``joint1 ... jointN``; names must be unique. ``base`` and
    ``tool`` are rigid 4x4 transforms (default identity), validated to 1e-9.
    """
    links = tuple(links)
    if not links:
        raise ArmInputError("links: a chain needs at least one link")
    named = []
    for i, link in enumerate(links, start=1):
        if not isinstance(link, DHLink):
            raise ArmInputError(f"links[{i - 1}] must be a DHLink, got {type(link).__name__}")
        named.append(link if link.name else DHLink(**{**link.__dict__, "name": f"joint{i}"}))
    names = [link.name for link in named]
    if len(set(names)) != len(names):
        raise ArmInputError(f"links: joint names must be unique, got {names}")
    B = _readonly(check_transform(np.eye(4) if base is None else base, "base"))
    T = _readonly(check_transform(np.eye(4) if tool is None else tool, "tool"))
    return DHChain(tuple(named), B, T)


def check_joint_vector(chain: DHChain, q, name: str = "q") -> np.ndarray:
    """``q`` as a float array of ``chain.n`` finite values, or a ``ValueError`` naming the problem."""
    try:
        v = np.array(q, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ArmInputError(f"{name} must be {chain.n} joint values, got {q!r}") from None
    if v.size != chain.n:
        raise ArmInputError(f"{name} must have {chain.n} joint values ({', '.join(chain.names)}), got {v.size}")
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        i = int(bad[0])
        raise ArmInputError(f"{name}[{i}] ({chain.links[i].name}) must be finite, got {v[i]}")
    return v


def check_joint_values(chain: DHChain, q, name: str = "q") -> np.ndarray:
    """:func:`check_joint_vector`, and every joint value within the range any joint limit can have:
    ±2π rad for a revolute joint (:data:`MAX_REVOLUTE`), ±10 m for a prismatic one
    (:data:`MAX_LENGTH`). A value beyond it is no pose of the arm but a unit slip (degrees or
    millimetres): :class:`ArmInputError` naming the joint, the value and the range, with a
    "did you mean degrees?" / "did you mean mm?" hint."""
    v = check_joint_vector(chain, q, name)
    for i, (link, x) in enumerate(zip(chain.links, v.tolist(), strict=True)):
        bound, unit = (MAX_REVOLUTE, "rad") if link.kind == "revolute" else (MAX_LENGTH, "m")
        if abs(x) > bound + _VALUE_SLACK:
            raise ArmInputError(
                f"{name}[{i}] ({link.name}) = {x:.6g} {unit} is outside ±{bound:.6g} {unit}, the widest range "
                f"a {link.kind} joint's limits may have" + unit_hint(x, -bound, bound, unit)
            )
    return v


def limit_violations(chain: DHChain, q, *, tol: float = 0.0) -> tuple[str, ...]:
    """Human-readable list of joint-limit violations of ``q`` (empty when within limits)."""
    v = check_joint_vector(chain, q)
    out = []
    for link, x in zip(chain.links, v, strict=True):
        if x < link.lower - tol or x > link.upper + tol:
            unit = "rad" if link.kind == "revolute" else "m"
            out.append(f"{link.name} = {x:.6g} {unit} outside [{link.lower:.6g}, {link.upper:.6g}]")
    return tuple(out)


@dataclass(frozen=True, eq=False)
class ChainFrames:
    """All frames of a chain at one joint vector (read-only 4x4 arrays, world coordinates).

    ``frames[0]`` is the base frame (frame 0), ``frames[i]`` frame ``i`` after joint ``i``,
    ``frames[n + 1]`` the tool frame.
    """

    q: np.ndarray
    frames: tuple[np.ndarray, ...]

    @property
    def end(self) -> np.ndarray:
        """Tool frame ``T`` (4x4)."""
        return self.frames[-1]

    @property
    def position(self) -> np.ndarray:
        """Tool position [m]."""
        return self.frames[-1][:3, 3].copy()

    @property
    def rotation(self) -> np.ndarray:
        """Tool orientation (3x3)."""
        return self.frames[-1][:3, :3].copy()

    def origin(self, i: int) -> np.ndarray:
        """Origin of frame ``i`` (0 = base, n + 1 = tool) [m]."""
        return self.frames[i][:3, 3].copy()


def forward_kinematics(chain: DHChain, q, *, check_limits: bool = False) -> ChainFrames:
    """Every frame of the chain at ``q`` [rad or m] (arm thesis 2.16). With ``check_limits`` a joint
    vector outside the limits raises :class:`JointLimitError`; without, a revolute value beyond
    ±2π (or a prismatic one beyond ±10 m) still raises :class:`ArmInputError` ("did you mean
    degrees?"), see :func:`check_joint_values`."""
    v = check_joint_values(chain, q)
    if check_limits:
        bad = limit_violations(chain, v)
        if bad:
            raise JointLimitError("joint limits violated: " + "; ".join(bad))
    T = np.array(chain.base)
    frames = [_readonly(T)]
    for link, x in zip(chain.links, v, strict=True):
        T = T @ link.transform(x)
        frames.append(_readonly(T))
    frames.append(_readonly(T @ chain.tool))
    return ChainFrames(_readonly(v), tuple(frames))


def geometric_jacobian(chain: DHChain, q) -> np.ndarray:
    """Geometric Jacobian (6 x n) of the tool frame in world coordinates.

    Rows 0-2: linear velocity of the tool origin; rows 3-5: angular velocity. Column ``i`` is
    ``[z × (p - o); z]`` for a revolute joint and ``[z; 0]`` for a prismatic one, with ``z``,
    ``o`` the axis and origin of frame ``i-1``.
    """
    fr = forward_kinematics(chain, q)
    p = fr.frames[-1][:3, 3]
    J = np.zeros((6, chain.n))
    for i, link in enumerate(chain.links):
        z, o = fr.frames[i][:3, 2], fr.frames[i][:3, 3]
        if link.kind == "revolute":
            J[:3, i] = np.cross(z, p - o)
            J[3:, i] = z
        else:
            J[:3, i] = z
    return J


@dataclass(frozen=True, eq=False)
class CasadiChain:
    """The chain as CasADi functions (SX graphs; call with numbers or symbols).

    Attributes:
        chain: The numeric chain they were built from.
        fk: ``q (n) -> (p (3x1) [m], R (3x3))``, tool pose in world coordinates.
        jacobian: ``q (n) -> J (6xn)``, geometric Jacobian as :func:`geometric_jacobian`.
        pose: ``q (n) -> (x (12x1), dx/dq (12xn))`` with ``x = [p; R[:, 0]; R[:, 1]; R[:, 2]]``
            and its exact derivative (the ``(value, jacobian)`` pair the SQP IK core expects).
        frames: ``q (n) -> (T_0, ..., T_{n+1})`` every frame (4x4), as :func:`forward_kinematics`.
    """

    chain: DHChain
    fk: ca.Function
    jacobian: ca.Function
    pose: ca.Function
    frames: ca.Function


def build_casadi_chain(chain: DHChain) -> CasadiChain:
    """Build the CasADi functions of ``chain`` (see :class:`CasadiChain`)."""
    n = chain.n
    q = ca.SX.sym("q", n)
    T = ca.SX(np.asarray(chain.base))
    frames = [T]
    for i, link in enumerate(chain.links):
        if link.kind == "revolute":
            A = dh_transform_ca(link.a, link.alpha, link.d, link.theta + q[i])
        else:
            A = dh_transform_ca(link.a, link.alpha, link.d + q[i], link.theta)
        T = T @ A
        frames.append(T)
    frames.append(T @ ca.SX(np.asarray(chain.tool)))
    end = frames[-1]
    p, R = end[:3, 3], end[:3, :3]
    cols = []
    for i, link in enumerate(chain.links):
        z, o = frames[i][:3, 2], frames[i][:3, 3]
        cols.append(ca.vertcat(ca.cross(z, p - o), z) if link.kind == "revolute" else ca.vertcat(z, ca.SX.zeros(3)))
    J = ca.horzcat(*cols)
    x = ca.vertcat(p, ca.reshape(R, 9, 1))
    return CasadiChain(
        chain=chain,
        fk=ca.Function("dh_fk", [q], [p, R], ["q"], ["p", "R"]),
        jacobian=ca.Function("dh_jacobian", [q], [J], ["q"], ["J"]),
        pose=ca.Function("dh_pose", [q], [x, ca.jacobian(x, q)], ["q"], ["x", "dx_dq"]),
        frames=ca.Function("dh_frames", [q], frames, ["q"], [f"T{i}" for i in range(n + 2)]),
    )
