"""Symbolic geometry of the hitch: points of one side and of the implement.

Every function takes and returns CasADi expressions (SX), so the model built from
them is differentiable by automatic differentiation. Frame: right-handed tractor
frame, origin midway between the lower-link pivots at pivot height, x to the
driver's left, y rearward, z up. ``side`` is +1 for the left side (at +x) and -1
for the right side; per-side points in the profile are given for the left side
with x pointing outward and are mirrored with ``side``.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from planner.profiles.hitch import Profile

__all__ = [
    "SideGeometry",
    "side_geometry",
    "link_direction",
    "bracket_direction",
    "lift_arm_end",
    "link_points",
    "solve_link_angles",
    "closure_residual",
    "mast_frame",
    "mast_point",
    "direction_angles",
]

LEFT, RIGHT = 1.0, -1.0


@dataclass(frozen=True)
class SideGeometry:
    """Fixed numbers of one side [m], already mirrored into the tractor frame."""

    side: float
    pivot: tuple[float, float, float]  # L0 or R0
    lift_arm_pivot: tuple[float, float, float]  # Q
    limiter_point: tuple[float, float, float]  # C
    link_length: float  # l_vv
    rod_attachment: float  # d_O^A
    bracket_position: float  # d_O^B'
    bracket_offset: float  # d_B^B'
    lift_arm_length: float  # d_S^Q


def side_geometry(profile: Profile, side: float) -> SideGeometry:
    g = profile.geometry
    px = side * g.lower_link_pivot_span / 2.0
    q = g.lift_arm_pivot
    c = g.limiter_tractor_point
    return SideGeometry(
        side=side,
        pivot=(px, 0.0, 0.0),
        lift_arm_pivot=(px + side * q[0], q[1], q[2]),
        limiter_point=(px + side * c[0], c[1], c[2]),
        link_length=g.lower_link_length,
        rod_attachment=g.lift_rod_attachment,
        bracket_position=g.limiter_bracket_position,
        bracket_offset=g.limiter_bracket_offset,
        lift_arm_length=g.lift_arm_length,
    )


def link_direction(theta_x, theta_z):
    """Unit direction of a lower link, fixed XYZ rotation R_z(θz)·R_x(θx)·e_y (thesis 2.1, 2.19)."""
    return ca.vertcat(-ca.cos(theta_x) * ca.sin(theta_z), ca.cos(theta_z) * ca.cos(theta_x), ca.sin(theta_x))


def bracket_direction(theta_z, side: float):
    """Horizontal outward unit vector of the limiter bracket B'→B (thesis 2.8, mirrored for the right)."""
    return side * ca.vertcat(ca.cos(theta_z), ca.sin(theta_z), 0)


def lift_arm_end(sg: SideGeometry, theta_e):
    """Lift-arm end S for lift-arm angle θ_E (thesis 2.14); the arm turns about the lateral axis."""
    q = ca.DM(sg.lift_arm_pivot)
    return q + sg.lift_arm_length * ca.vertcat(0, ca.cos(theta_e), ca.sin(theta_e))


def link_points(sg: SideGeometry, theta_x, theta_z) -> dict[str, ca.SX]:
    """Points on one lower link: A (lift rod), B' and B (limiter bracket), link end (thesis 2.1, 2.7, 2.8)."""
    p = ca.DM(sg.pivot)
    d = link_direction(theta_x, theta_z)
    b_prime = p + sg.bracket_position * d
    return {
        "A": p + sg.rod_attachment * d,
        "Bp": b_prime,
        "B": b_prime + sg.bracket_offset * bracket_direction(theta_z, sg.side),
        "end": p + sg.link_length * d,
    }


def _theta_x_from_rod(sg: SideGeometry, s_point, rod_length, theta_z):
    """Closed-form θx with θz given: A on the sphere |A−S| = rod (lower branch, thesis 2.17-2.18)."""
    s = s_point - ca.DM(sg.pivot)
    a = sg.rod_attachment
    hs = -ca.sin(theta_z) * s[0] + ca.cos(theta_z) * s[1]
    k1 = (a**2 + ca.sumsqr(s) - rod_length**2) / 2.0
    r = ca.sqrt(hs**2 + s[2] ** 2)
    arg = ca.fmin(1.0, ca.fmax(-1.0, k1 / (a * r)))
    return ca.atan2(s[2], hs) - ca.acos(arg)


def _theta_z_from_limiter(sg: SideGeometry, limiter_length, theta_x):
    """Closed-form θz with θx given: B on the sphere |B−C| = limiter (thesis 2.10-2.13, exact)."""
    c = ca.DM(sg.limiter_point) - ca.DM(sg.pivot)
    b, e, sd = sg.bracket_position, sg.bracket_offset, sg.side
    k2 = (b**2 + e**2 + float(ca.sumsqr(c)) - limiter_length**2) / 2.0
    rhs = k2 - b * ca.sin(theta_x) * float(c[2])
    p_ = b * ca.cos(theta_x) * float(c[1]) + e * sd * float(c[0])
    q_ = -b * ca.cos(theta_x) * float(c[0]) + e * sd * float(c[1])
    arg = ca.fmin(1.0, ca.fmax(-1.0, rhs / ca.sqrt(p_**2 + q_**2)))
    return ca.atan2(q_, p_) + sd * ca.acos(arg)


def closure_residual(sg: SideGeometry, s_point, rod_length, limiter_length, theta_x, theta_z):
    """Loop-closure equations of one side: |A−S|² − rod², |B−C|² − limiter² [m²]."""
    pts = link_points(sg, theta_x, theta_z)
    c = ca.DM(sg.limiter_point)
    return ca.vertcat(ca.sumsqr(pts["A"] - s_point) - rod_length**2, ca.sumsqr(pts["B"] - c) - limiter_length**2)


def solve_link_angles(sg: SideGeometry, s_point, rod_length, limiter_length, *, sweeps: int = 2, newton: int = 3):
    """Lower-link angles (θx, θz) of one side from its lift-rod and limiter lengths.

    Exact to machine precision: alternating closed-form solutions of each constraint
    (Gauss-Seidel ``sweeps``) seed ``newton`` unrolled Newton steps on
    :func:`closure_residual`. Returns (θx, θz, residual) where ``residual`` holds the
    two length errors [m]; callers must check it (no solution ⇒ large residual).
    The expressions are meant for values; differentiate through the implicit-function
    theorem (see :mod:`planner.model.kinematics`), not through the iterations.
    """
    tz = ca.SX(0)
    tx = ca.SX(0)
    for _ in range(sweeps):
        tx = _theta_x_from_rod(sg, s_point, rod_length, tz)
        tz = _theta_z_from_limiter(sg, limiter_length, tx)
    th = ca.vertcat(tx, tz)
    sym = ca.SX.sym("th", 2)
    g = closure_residual(sg, s_point, rod_length, limiter_length, sym[0], sym[1])
    jac = ca.jacobian(g, sym)
    for _ in range(newton):
        gk, jk = ca.substitute([g, jac], [sym], [th])
        det = jk[0, 0] * jk[1, 1] - jk[0, 1] * jk[1, 0]
        step = ca.vertcat(jk[1, 1] * gk[0] - jk[0, 1] * gk[1], -jk[1, 0] * gk[0] + jk[0, 0] * gk[1]) / det
        th = th - step
    pts = link_points(sg, th[0], th[1])
    c = ca.DM(sg.limiter_point)
    residual = ca.vertcat(ca.norm_2(pts["A"] - s_point) - rod_length, ca.norm_2(pts["B"] - c) - limiter_length)
    return th[0], th[1], residual


def mast_frame(left_end, right_end):
    """Implement frame at the lower hitch axis: (x_i along R→L, u0 = vertical projected ⟂ x_i, w = x_i × u0)."""
    v = left_end - right_end
    xi = v / ca.norm_2(v)
    ez = ca.DM([0.0, 0.0, 1.0])
    up = ez - xi[2] * xi
    u0 = up / ca.norm_2(up)
    return xi, u0, ca.cross(xi, u0)


def mast_point(left_end, right_end, h_point, top_length, mast_height):
    """Mast point U: circle (centre T, radius d_T^U, ⟂ L−R) ∩ sphere (centre H, radius top) (thesis 2.23-2.35).

    Exact vector solution on the upright branch. Returns (U, pitch, reach) where
    pitch is the right-hand rotation of the mast about x_i from u0 and ``reach`` is
    the cosine argument; |reach| > 1 means the top link cannot reach the mast.
    """
    t = (left_end + right_end) / 2.0
    xi, u0, w = mast_frame(left_end, right_end)
    p = t - h_point
    a = ca.dot(p, u0)
    b = ca.dot(p, w)
    c = (top_length**2 - ca.sumsqr(p) - mast_height**2) / (2.0 * mast_height)
    reach = c / ca.sqrt(a**2 + b**2)
    phi = ca.atan2(b, a) + ca.acos(ca.fmin(1.0, ca.fmax(-1.0, reach)))
    pitch = ca.atan2(ca.sin(phi), ca.cos(phi))
    u = t + mast_height * (ca.cos(pitch) * u0 + ca.sin(pitch) * w)
    return u, pitch, reach


def direction_angles(vec):
    """(yaw, elevation) of a direction: yaw = atan2(−v_x, v_y) (as θz), elevation above the horizontal."""
    return ca.atan2(-vec[0], vec[1]), ca.atan2(vec[2], ca.sqrt(vec[0] ** 2 + vec[1] ** 2))
