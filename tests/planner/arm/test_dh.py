"""Denavit-Hartenberg chains (planner.arm.dh) and the source's DH formulas.

Truth: products of elementary transforms, the closed forms of the anthropomorphic arm with
spherical wrist (the source's 2.21-2.24, 2.37, 2.62 as corrected here), hand-derived
kinematics of a prismatic chain, finite differences for the Jacobians. Where the source's
typeset formula is wrong the test shows that it fails the same check.
"""

import math

import numpy as np
import pytest

from planner.arm.dh import (
    DHLink,
    JointLimitError,
    build_casadi_chain,
    build_dh_chain,
    dh_transform,
    forward_kinematics,
    geometric_jacobian,
    limit_violations,
)
from planner.arm.profile import load_arm_profile
from planner.arm.transforms import ArmInputError, homogeneous, rotx, roty, rotz, translation, vee

SEED = 20261125
H = math.pi / 2
C, S = math.cos, math.sin


def table21_chain(a2=0.7, d4=0.5, d6=0.2, d1=0.0, theta3=0.0):
    """The source's Table 2.1 (d1 = 0 there)."""
    return build_dh_chain(
        [
            DHLink(0, H, d1, 0),
            DHLink(a2, 0, 0, 0),
            DHLink(0, H, 0, theta3),
            DHLink(0, -H, d4, 0),
            DHLink(0, H, 0, 0),
            DHLink(0, 0, d6, 0),
        ]
    )


def elementary_dh(a, alpha, d, theta):
    R = np.eye(4)
    R[:3, :3] = rotz(theta)
    X = np.eye(4)
    X[:3, :3] = rotx(alpha)
    return R @ translation(0, 0, d) @ translation(a, 0, 0) @ X


# --------------------------------------------------------------------------- link transform
def test_dh_transform_is_the_product_of_elementary_transforms():
    rng = np.random.default_rng(SEED)
    for a, alpha, d, theta in rng.uniform(-3, 3, size=(100, 4)):
        np.testing.assert_allclose(dh_transform(a, alpha, d, theta), elementary_dh(a, alpha, d, theta), atol=1e-14)


def printed_2_19(a, alpha, d, theta):
    """The source's 2.19 as typeset (a_1 read as a)."""
    return np.array(
        [
            [C(theta), -S(theta) * C(alpha), C(theta) * S(alpha), a * C(theta)],
            [S(theta), C(theta) * C(alpha), -S(alpha), d * C(theta)],
            [0, S(alpha), C(alpha), 0],
            [0, 0, 0, 1],
        ]
    )


def test_source_2_19_as_printed_fails():
    """Erratum 2.19: entries (1,3), (2,3), (2,4), (3,4) are wrong as typeset."""
    rng = np.random.default_rng(SEED)
    wrong = set()
    for a, alpha, d, theta in rng.uniform(0.2, 1.3, size=(20, 4)):
        diff = np.abs(printed_2_19(a, alpha, d, theta) - elementary_dh(a, alpha, d, theta)) > 1e-9
        wrong |= {(int(i) + 1, int(j) + 1) for i, j in zip(*np.nonzero(diff), strict=True)}
    assert wrong == {(1, 3), (2, 3), (2, 4), (3, 4)}


# --------------------------------------------------------------------------- Table 2.1 closed forms
def closed_form_0T6(q, a2, d4, d6):
    """n, s, a, p of the anthropomorphic arm with spherical wrist (2.21-2.24, corrected)."""
    c1, s1, c2, s2, c4, s4, c5, s5, c6, s6 = (f(x) for x in (q[0], q[1], q[3], q[4], q[5]) for f in (C, S))
    c23, s23 = C(q[1] + q[2]), S(q[1] + q[2])
    n = np.array(
        [
            c1 * (c23 * (c4 * c5 * c6 - s4 * s6) - s23 * s5 * c6) + s1 * (s4 * c5 * c6 + c4 * s6),
            s1 * (c23 * (c4 * c5 * c6 - s4 * s6) - s23 * s5 * c6) - c1 * (s4 * c5 * c6 + c4 * s6),
            s23 * (c4 * c5 * c6 - s4 * s6) + c23 * s5 * c6,
        ]
    )
    s = np.array(
        [
            c1 * (-c23 * (c4 * c5 * s6 + s4 * c6) + s23 * s5 * s6) + s1 * (-s4 * c5 * s6 + c4 * c6),
            s1 * (-c23 * (c4 * c5 * s6 + s4 * c6) + s23 * s5 * s6) - c1 * (-s4 * c5 * s6 + c4 * c6),
            -s23 * (c4 * c5 * s6 + s4 * c6) - c23 * s5 * s6,
        ]
    )
    a = np.array(
        [
            c1 * (c23 * c4 * s5 + s23 * c5) + s1 * s4 * s5,
            s1 * (c23 * c4 * s5 + s23 * c5) - c1 * s4 * s5,
            s23 * c4 * s5 - c23 * c5,
        ]
    )
    p = np.array(
        [
            a2 * c1 * c2 + d4 * c1 * s23 + d6 * a[0],
            a2 * s1 * c2 + d4 * s1 * s23 + d6 * a[1],
            a2 * s2 - d4 * c23 + d6 * a[2],
        ]
    )
    return n, s, a, p


def test_table21_chain_matches_corrected_closed_forms_and_typeset_ones_fail():
    rng = np.random.default_rng(SEED)
    chain = table21_chain()
    bad_nz = bad_s = bad_ay = bad_py = 0
    for q in rng.uniform(-math.pi, math.pi, size=(200, 6)):
        T = forward_kinematics(chain, q).end
        n, s, a, p = closed_form_0T6(q, 0.7, 0.5, 0.2)
        for got, want in ((T[:3, 0], n), (T[:3, 1], s), (T[:3, 2], a), (T[:3, 3], p)):
            np.testing.assert_allclose(got, want, atol=1e-14)
        c1, s1, c4, s4, c5, s5, c6, s6 = C(q[0]), S(q[0]), C(q[3]), S(q[3]), C(q[4]), S(q[4]), C(q[5]), S(q[5])
        c23, s23 = C(q[1] + q[2]), S(q[1] + q[2])
        # 2.21 z row as printed: "+ C23 S5 S6" (should be C23 S5 C6).
        bad_nz += abs(s23 * (c4 * c5 * c6 - s4 * s6) + c23 * s5 * s6 - n[2]) > 1e-9
        # 2.22 x row as printed: "-C23(C4C5C6 + C4S6) + S23S5C6" and "S1(-S4C5C6 + C4S6)".
        s_x = c1 * (-c23 * (c4 * c5 * c6 + c4 * s6) + s23 * s5 * c6) + s1 * (-s4 * c5 * c6 + c4 * s6)
        s_z = -s23 * (c4 * c5 * c6 + s4 * s6) - c23 * s5 * s6  # z row as printed
        bad_s += abs(s_x - s[0]) > 1e-9 and abs(s_z - s[2]) > 1e-9
        # 2.23 / 2.24 y rows as printed: "+ C1 S4 S5" (should be minus).
        a_y = s1 * (c23 * c4 * s5 + s23 * C(q[4])) + c1 * s4 * s5
        bad_ay += abs(a_y - a[1]) > 1e-9
        bad_py += abs(0.7 * s1 * C(q[1]) + 0.5 * s1 * s23 + 0.2 * a_y - p[1]) > 1e-9
    assert min(bad_nz, bad_s, bad_ay, bad_py) >= 190


def three_link_T03(q1, q2, q3, a2, a3):
    """The source's T03 of the three-link arm as in its Matlab listing (figure 3.3)."""
    c1, s1, c2, s2, c23, s23 = C(q1), S(q1), C(q2), S(q2), C(q2 + q3), S(q2 + q3)
    return np.array(
        [
            [c1 * c23, -c1 * s23, s1, c1 * (a2 * c2 + a3 * c23)],
            [s1 * c23, -s1 * s23, -c1, s1 * (a2 * c2 + a3 * c23)],
            [s23, c23, 0, a2 * s2 + a3 * s23],
            [0, 0, 0, 1],
        ]
    )


def test_three_link_T03_listing_is_right_and_2_37_2_25_as_printed_fail():
    rng = np.random.default_rng(SEED)
    three = build_dh_chain([DHLink(0, H, 0, 0), DHLink(1.0, 0, 0, 0), DHLink(0.5, 0, 0, 0)])
    for q in rng.uniform(-3, 3, size=(50, 3)):
        T = forward_kinematics(three, q).end
        listing = three_link_T03(*q, 1.0, 0.5)
        np.testing.assert_allclose(T, listing, atol=1e-14)
        c1, s1 = C(q[0]), S(q[0])
        printed_2_37 = listing.copy()
        printed_2_37[1, 2] = c1  # 2.37 prints +c1
        assert abs(printed_2_37[1, 2] - T[1, 2]) > 1e-6 or abs(c1) < 1e-6
        printed_2_25 = listing.copy()
        printed_2_25[0, 1], printed_2_25[1, 1] = -listing[0, 1], -listing[1, 1]  # "C1 S23", "S1 S23"
        printed_2_25[1, 3] = s1 * 1.0 * C(q[1])  # "S1 a2 C2": the a3 C23 term is missing
        assert np.max(np.abs(printed_2_25 - T)) > 1e-6


def test_source_wrist_frame_equals_dh_frame_3_with_offset():
    """The source's R03 · rotx(π/2) · roty(π/2) (figure 3.3) is DH frame 3 of Table 2.1 when
    θ3 = q3 + π/2 and d4 = a3; frame 4's origin is the three-link arm's end (the wrist centre)."""
    rng = np.random.default_rng(SEED)
    chain = table21_chain(a2=0.1, d4=0.05, d6=0.02, theta3=H)
    for q in rng.uniform(-math.pi, math.pi, size=(50, 6)):
        fr = forward_kinematics(chain, q)
        T3 = three_link_T03(q[0], q[1], q[2], 0.1, 0.05)
        np.testing.assert_allclose(fr.frames[3][:3, :3], T3[:3, :3] @ rotx(H) @ roty(H), atol=1e-14)
        np.testing.assert_allclose(fr.origin(4), T3[:3, 3], atol=1e-15)
        np.testing.assert_allclose(fr.origin(5), T3[:3, 3], atol=1e-15)
        R36 = fr.frames[3][:3, :3].T @ fr.frames[6][:3, :3]
        np.testing.assert_allclose(R36, rotz(q[3]) @ roty(q[4]) @ rotz(q[5]), atol=1e-14)


def test_wrist_transforms_2_59_to_2_62():
    """Spherical wrist alone (Table 2.1 links 4-6 with d4 = 0): 2.60 is right; 2.59, 2.61 and
    2.62 as typeset are not."""
    rng = np.random.default_rng(SEED)
    d6 = 0.3
    for q4, q5, q6 in rng.uniform(0.2, 1.3, size=(20, 3)):
        A4, A5, A6 = dh_transform(0, -H, 0, q4), dh_transform(0, H, 0, q5), dh_transform(0, 0, d6, q6)
        c4, s4, c5, s5, c6, s6 = C(q4), S(q4), C(q5), S(q5), C(q6), S(q6)
        p259 = np.array([[c4, 0, -s4, 0], [s4, 1, c4, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        p260 = np.array([[c5, 0, s5, 0], [s5, 0, -c5, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
        p261 = np.array([[c6, -s6, 0, 0], [s6, 1, c6, 0], [0, 0, 1, d6], [0, 0, 0, 1]])
        p262 = np.array(
            [
                [c4 * c5 * c6, -c4 * c5 * s6 - s4 * c6, c4 * s5, c4 * s5 * d6],
                [s4 * c5 * c6, -s4 * c5 * s6 + c4 * c6, s4 * s5, s4 * s5 * d6],
                [-s5 * c6, s5 * s6, c5, d6],
                [0, 0, 0, 1],
            ]
        )
        np.testing.assert_allclose(p260, A5, atol=1e-15)
        assert np.max(np.abs(p259 - A4)) > 0.5
        assert np.max(np.abs(p261 - A6)) > 0.5
        A36 = A4 @ A5 @ A6
        assert np.max(np.abs(p262 - A36)) > 1e-3
        corrected = p262.copy()
        corrected[0, 0] -= s4 * s6
        corrected[1, 0] += c4 * s6
        corrected[2, 3] = c5 * d6
        np.testing.assert_allclose(corrected, A36, atol=1e-14)


# --------------------------------------------------------------------------- prismatic joints, base, tool
def test_prismatic_chain_by_hand():
    """Waist (revolute, height h) then a horizontal telescopic boom along z1 = (s1, -c1, 0)."""
    h = 0.8
    chain = build_dh_chain(
        [
            DHLink(0, H, h, 0, name="waist"),
            DHLink(0, 0, 0.1, 0, kind="prismatic", lower=0.0, upper=2.0, name="boom"),
        ]
    )
    for q1, q2 in ((0.0, 0.5), (0.7, 1.3), (-2.0, 0.0)):
        fr = forward_kinematics(chain, [q1, q2])
        np.testing.assert_allclose(fr.position, [(q2 + 0.1) * S(q1), -(q2 + 0.1) * C(q1), h], atol=1e-15)
        J = geometric_jacobian(chain, [q1, q2])
        np.testing.assert_allclose(J[:, 1], [S(q1), -C(q1), 0, 0, 0, 0], atol=1e-15)
        np.testing.assert_allclose(J[:, 0], [(q2 + 0.1) * C(q1), (q2 + 0.1) * S(q1), 0, 0, 0, 1], atol=1e-15)


def test_base_and_tool_transforms():
    rng = np.random.default_rng(SEED)
    bare = table21_chain()
    base = homogeneous(rotz(0.3) @ rotx(-0.2), [0.5, -1.0, 0.9])
    tool = homogeneous(roty(0.4), [0.0, 0.05, 0.12])
    chain = build_dh_chain(bare.links, base=base, tool=tool)
    for q in rng.uniform(-3, 3, size=(20, 6)):
        np.testing.assert_allclose(
            forward_kinematics(chain, q).end, base @ forward_kinematics(bare, q).end @ tool, atol=1e-14
        )


# --------------------------------------------------------------------------- Jacobians and CasADi
def mixed_chain():
    links = list(table21_chain().links)
    links[1] = DHLink(0.7, 0.0, 0.1, 0.2, kind="prismatic", lower=-1, upper=1, name="slide")
    base = homogeneous(rotx(0.5), [0.1, 0.2, 0.3])
    return build_dh_chain(links, base=base, tool=homogeneous(rotz(0.3), [0.01, 0.0, 0.05]))


@pytest.mark.parametrize("make", [table21_chain, mixed_chain, lambda: load_arm_profile().chain()])
def test_geometric_jacobian_against_finite_differences(make):
    rng = np.random.default_rng(SEED)
    chain = make()
    eps = 1e-6
    for q in rng.uniform(-1, 1, size=(10, chain.n)):
        J = geometric_jacobian(chain, q)
        fr = forward_kinematics(chain, q)
        for i in range(chain.n):
            dq = np.zeros(chain.n)
            dq[i] = eps
            plus, minus = forward_kinematics(chain, q + dq), forward_kinematics(chain, q - dq)
            np.testing.assert_allclose(J[:3, i], (plus.position - minus.position) / (2 * eps), atol=1e-8)
            dR = (plus.rotation - minus.rotation) / (2 * eps)
            np.testing.assert_allclose(J[3:, i], vee(dR @ fr.rotation.T), atol=1e-8)


@pytest.mark.parametrize("make", [table21_chain, mixed_chain])
def test_casadi_functions_equal_numpy(make):
    rng = np.random.default_rng(SEED)
    chain = make()
    fns = build_casadi_chain(chain)
    for q in rng.uniform(-1, 1, size=(10, chain.n)):
        fr = forward_kinematics(chain, q)
        p, R = fns.fk(q)
        np.testing.assert_allclose(np.array(p).ravel(), fr.position, atol=1e-14)
        np.testing.assert_allclose(np.array(R), fr.rotation, atol=1e-14)
        np.testing.assert_allclose(np.array(fns.jacobian(q)), geometric_jacobian(chain, q), atol=1e-13)
        for T_ca, T in zip(fns.frames(q), fr.frames, strict=True):
            np.testing.assert_allclose(np.array(T_ca), T, atol=1e-14)
        x, dx = (np.array(v) for v in fns.pose(q))
        np.testing.assert_allclose(x.ravel(), np.concatenate([fr.position, fr.rotation.T.ravel()]), atol=1e-14)
        # d vec(R)/dq_i = vec([w_i]x R) with w_i the angular column of the geometric Jacobian.
        J = geometric_jacobian(chain, q)
        for i in range(chain.n):
            w = J[3:, i]
            dR = np.cross(w[:, None], fr.rotation, axis=0)
            np.testing.assert_allclose(dx[3:, i], dR.T.ravel(), atol=1e-13)
            np.testing.assert_allclose(dx[:3, i], J[:3, i], atol=1e-13)


# --------------------------------------------------------------------------- limits and bad input
def test_limits():
    chain = build_dh_chain([DHLink(0, 0, 0, 0, lower=-1, upper=1, name="a"), DHLink(1, 0, 0, 0, name="b")])
    assert limit_violations(chain, [0.5, 3.0]) == ()
    (msg,) = limit_violations(chain, [1.5, 0.0])
    assert "a = 1.5" in msg and "[-1, 1]" in msg
    with pytest.raises(JointLimitError, match="a = -2"):
        forward_kinematics(chain, [-2.0, 0.0], check_limits=True)
    forward_kinematics(chain, [-2.0, 0.0])  # not checked by default


def test_bad_input_is_named():
    chain = table21_chain()
    with pytest.raises(ValueError, match="6 joint values"):
        forward_kinematics(chain, [0.0] * 5)
    with pytest.raises(ValueError, match=r"q\[2\] \(joint3\) must be finite"):
        forward_kinematics(chain, [0, 0, float("nan"), 0, 0, 0])
    with pytest.raises(ValueError, match="lower < upper"):
        DHLink(0, 0, 0, 0, lower=1.0, upper=1.0, name="j")
    with pytest.raises(ValueError, match="kind must be one of"):
        DHLink(0, 0, 0, 0, kind="helical")
    with pytest.raises(ValueError, match=r"j\.a must be finite"):
        DHLink(float("inf"), 0, 0, 0, name="j")
    with pytest.raises(ValueError, match=r"j\.lower = -10 rad is outside the allowed ±6\.28319 rad"):
        DHLink(0, 0, 0, 0, lower=-10, upper=0, name="j")
    with pytest.raises(ValueError, match="unique"):
        build_dh_chain([DHLink(0, 0, 0, 0, name="x"), DHLink(0, 0, 0, 0, name="x")])
    with pytest.raises(ValueError, match="at least one link"):
        build_dh_chain([])
    with pytest.raises(ValueError, match="base rotation block is not a rotation"):
        build_dh_chain(chain.links, base=np.diag([2.0, 1.0, 1.0, 1.0]))


# --------------------------------------------------------------------------- unit slips
@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(a=100.0), r"j\.a = 100 m is outside the allowed \[-10, 10\] m; did you mean mm\? 100 mm = 0\.1 m"),
        (dict(d=50.0), r"j\.d = 50 m is outside the allowed \[-10, 10\] m; did you mean mm\? 50 mm = 0\.05 m"),
        (dict(theta=90.0), r"j\.theta = 90 rad is outside the allowed ±2π rad; did you mean degrees\? 90 deg"),
        (
            dict(lower=-180.0, upper=180.0),
            r"j\.lower = -180 rad is outside the allowed ±6\.28319 rad for a revolute joint; "
            r"did you mean degrees\? -180 deg = -3\.14159 rad",
        ),
        (
            dict(kind="prismatic", lower=0.0, upper=500.0),
            r"j\.upper = 500 m is outside the allowed ±10 m for a prismatic joint; did you mean mm\? 500 mm = 0\.5 m",
        ),
        (dict(a=True), r"j\.a must be a number, got bool True"),
        (dict(d="0.1"), r"j\.d must be a number, got str '0\.1'"),
        (dict(name=5), r"name must be a string \(the joint's label\), got int 5"),
    ],
)
def test_dh_link_unit_slips_and_non_numbers_are_refused(kwargs, match):
    args = dict(a=0.0, alpha=0.0, d=0.0, theta=0.0, name="j") | kwargs
    with pytest.raises(ArmInputError, match=match):
        DHLink(**args)


def test_dh_link_bounds_accept_plausible_arms():
    DHLink(a=10.0, alpha=-2 * math.pi, d=-10.0, theta=2 * math.pi, lower=-2 * math.pi, upper=2 * math.pi)
    DHLink(0, 0, 0, 0, kind="prismatic", lower=-10.0, upper=10.0)
    DHLink(np.float64(0.1), np.int64(0), 0, 0)  # numpy numbers are numbers


def test_forward_kinematics_refuses_revolute_joints_in_degrees():
    chain = table21_chain()
    q_deg = [35.1493, -12.4968, 74.2324, 63.4518, 111.1249, -147.4508]  # the source's first solution, degrees
    with pytest.raises(
        ArmInputError,
        match=r"q\[0\] \(joint1\) = 35\.1493 rad is outside ±6\.28319 rad, the widest range a revolute joint's "
        r"limits may have; did you mean degrees\? 35\.1493 deg = 0\.613471 rad",
    ):
        forward_kinematics(chain, q_deg)
    with pytest.raises(ArmInputError, match=r"q\[1\] \(joint2\) = -7 rad .*did you mean degrees\?"):
        geometric_jacobian(chain, [0.0, -7.0, 0, 0, 0, 0])
    # ±2π itself (a limit may be 2π) and anything within it still evaluate
    forward_kinematics(chain, [2 * math.pi, -2 * math.pi, 6.0, -6.0, 0.0, 3.0])


def test_forward_kinematics_refuses_prismatic_joints_in_mm():
    chain = build_dh_chain([DHLink(0, 0, 0.1, 0, kind="prismatic", lower=0.0, upper=2.0, name="boom")])
    with pytest.raises(ArmInputError, match=r"q\[0\] \(boom\) = 1500 m is outside ±10 m.*did you mean mm\? 1500 mm"):
        forward_kinematics(chain, [1500.0])
    assert forward_kinematics(chain, [1.5]).position[2] == pytest.approx(1.6)
