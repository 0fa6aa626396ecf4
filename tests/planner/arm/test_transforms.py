"""Rotations, ZYZ Euler angles and homogeneous transforms (planner.arm.transforms).

Truth: hand-evaluated matrices, algebraic identities (orthonormality, composition, inverse),
round trips over random inputs with a fixed seed, and the source's own numbers.
"""

import math

import casadi as ca
import numpy as np
import pytest

from planner.arm.transforms import (
    EulerZYZ,
    RotationMatrixError,
    check_rotation,
    check_transform,
    euler_zyz_matrix,
    homogeneous,
    invert_transform,
    nearest_rotation,
    orthonormality_defect,
    rotation_distance,
    rotx,
    rotx_ca,
    roty,
    roty_ca,
    rotz,
    rotz_ca,
    skew,
    so3_log,
    solve_euler_zyz,
    translation,
    vee,
    wrap_angle,
)

SEED = 20261124
#: The source's target orientation (arm thesis 3.1), printed to four decimals.
R06_PRINTED = np.array([[-0.1219, -0.9917, 0.0406], [-0.1241, -0.0253, -0.9919], [0.9847, -0.1260, -0.1200]])


def random_rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


# --------------------------------------------------------------------------- elementary rotations
def test_elementary_rotations_by_hand():
    e = np.eye(3)
    # Positive right-hand quarter turns: x -> y about z, y -> z about x, z -> x about y.
    np.testing.assert_allclose(rotz(math.pi / 2) @ e[0], e[1], atol=1e-15)
    np.testing.assert_allclose(rotx(math.pi / 2) @ e[1], e[2], atol=1e-15)
    np.testing.assert_allclose(roty(math.pi / 2) @ e[2], e[0], atol=1e-15)
    c, s = math.cos(0.3), math.sin(0.3)
    np.testing.assert_array_equal(rotx(0.3), [[1, 0, 0], [0, c, -s], [0, s, c]])  # arm thesis 2.9
    np.testing.assert_array_equal(roty(0.3), [[c, 0, s], [0, 1, 0], [-s, 0, c]])  # 2.8
    np.testing.assert_array_equal(rotz(0.3), [[c, -s, 0], [s, c, 0], [0, 0, 1]])  # 2.7


def test_elementary_rotations_are_rotations_and_compose_about_their_axis():
    rng = np.random.default_rng(SEED)
    for rot in (rotx, roty, rotz):
        for a, b in rng.uniform(-7, 7, size=(20, 2)):
            R = rot(a)
            assert orthonormality_defect(R) < 1e-15
            assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-15)
            np.testing.assert_allclose(rot(a) @ rot(b), rot(a + b), atol=1e-14)
            np.testing.assert_allclose(rot(-a), R.T, atol=1e-15)


def test_casadi_rotations_equal_numpy():
    a = ca.SX.sym("a")
    for rot, rot_ca in ((rotx, rotx_ca), (roty, roty_ca), (rotz, rotz_ca)):
        f = ca.Function("f", [a], [rot_ca(a)])
        for v in (-2.5, 0.0, 0.7, 3.1):
            np.testing.assert_allclose(np.array(f(v)), rot(v), atol=1e-15)


def test_source_listing_rotz_has_a_zero_row():
    """Erratum: the Matlab ``rotz`` of figure 3.1 has last row [0, 0, 0]; it is singular."""
    g = 0.4
    listing_rotz = np.array([[math.cos(g), -math.sin(g), 0], [math.sin(g), math.cos(g), 0], [0, 0, 0]])
    assert np.linalg.det(listing_rotz) == 0.0
    assert orthonormality_defect(listing_rotz) == math.inf
    assert abs(np.linalg.det(rotz(g)) - 1.0) < 1e-15


def test_bad_angles_rejected():
    for bad in (float("nan"), float("inf"), "x", None):
        with pytest.raises(ValueError, match="angle"):
            rotx(bad)


# --------------------------------------------------------------------------- homogeneous transforms
def test_homogeneous_and_inverse():
    rng = np.random.default_rng(SEED)
    for _ in range(50):
        R, p = random_rotation(rng), rng.normal(size=3)
        T = homogeneous(R, p)
        np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
        np.testing.assert_allclose(T @ invert_transform(T), np.eye(4), atol=1e-14)
        np.testing.assert_allclose(invert_transform(T), np.linalg.inv(T), atol=1e-13)
        x = rng.normal(size=3)
        np.testing.assert_allclose((T @ np.append(x, 1))[:3], R @ x + p, atol=1e-14)
    np.testing.assert_array_equal(translation(1, 2, 3)[:3, 3], [1, 2, 3])


def test_post_and_pre_multiplication_rules():
    """Post-multiplying rotates about the moving axes, pre-multiplying about the base axes."""
    R = rotz(0.5)
    moved = R @ rotx(0.3)  # about the moving x axis = R's first column
    rodrigues_axis = R[:, 0]
    K = skew(rodrigues_axis)
    about_moving_x = np.eye(3) + math.sin(0.3) * K + (1 - math.cos(0.3)) * K @ K
    np.testing.assert_allclose(moved, about_moving_x @ R, atol=1e-15)
    np.testing.assert_allclose(moved[:, 0], R[:, 0], atol=1e-15)  # the moving x axis stays put
    R2 = roty(0.4) @ rotz(-1.0)
    base_moved = rotx(0.3) @ R2  # about the base x axis: x components of every axis stay put
    np.testing.assert_allclose(base_moved[0], R2[0], atol=1e-15)
    assert np.max(np.abs(base_moved[1:] - R2[1:])) > 0.05


def test_bad_transforms_rejected():
    with pytest.raises(RotationMatrixError, match="4x4"):
        check_transform(np.eye(3))
    T = np.eye(4)
    T[3, 0] = 1.0
    with pytest.raises(RotationMatrixError, match="last row"):
        check_transform(T)
    T = np.eye(4)
    T[0, 0] = -1.0
    with pytest.raises(RotationMatrixError, match="det"):
        check_transform(T)
    with pytest.raises(ValueError, match="position"):
        homogeneous(np.eye(3), [1.0, float("nan"), 0.0])


# --------------------------------------------------------------------------- SO(3) helpers
def test_log_and_distance():
    rng = np.random.default_rng(SEED)
    for angle in (0.0, 1e-12, 1e-6, 0.3, 2.0, math.pi - 1e-6, math.pi):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        K = skew(axis)
        R = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
        w = so3_log(R)
        assert np.linalg.norm(w) == pytest.approx(angle, abs=1e-12)
        if 1e-9 < angle < math.pi:
            np.testing.assert_allclose(w, angle * axis, atol=1e-9)
        assert rotation_distance(np.eye(3), R) == pytest.approx(angle, abs=1e-12)
    np.testing.assert_allclose(vee(skew([1.0, -2.0, 3.0])), [1.0, -2.0, 3.0])


def test_rotation_distance_is_accurate_for_tiny_angles():
    """arccos of the trace would give ~1e-8 for a 1e-12 rad rotation; the log map does not."""
    assert rotation_distance(rotz(1e-12), np.eye(3)) == pytest.approx(1e-12, rel=1e-3)


def test_nearest_rotation():
    rng = np.random.default_rng(SEED)
    for _ in range(50):
        R = random_rotation(rng)
        np.testing.assert_allclose(nearest_rotation(R), R, atol=1e-14)
        noisy = R + 1e-4 * rng.normal(size=(3, 3))
        P = nearest_rotation(noisy)
        assert orthonormality_defect(P) < 1e-14
        # The polar factor is at least as close as the original rotation.
        assert np.linalg.norm(P - noisy) <= np.linalg.norm(R - noisy) + 1e-15


def test_printed_source_rotation_is_not_orthonormal_but_projects_within_its_rounding():
    """R06 printed to four decimals: defect ~1e-4; its projection changes no entry by more than
    the half unit of the last printed digit (5e-5), so it is one of the rotations the print
    stands for."""
    defect = orthonormality_defect(R06_PRINTED)
    assert 5e-5 < defect < 2e-4
    P = nearest_rotation(R06_PRINTED)
    assert np.max(np.abs(P - R06_PRINTED)) < 5e-5
    np.testing.assert_array_equal(np.round(P, 4), R06_PRINTED)
    with pytest.raises(RotationMatrixError, match="allowed: <= 1e-09"):
        check_rotation(R06_PRINTED)
    check_rotation(R06_PRINTED, atol=1e-3)


# --------------------------------------------------------------------------- ZYZ Euler angles
def test_zyz_matrix_definition():
    phi, theta, psi = 0.3, -1.1, 2.5
    np.testing.assert_allclose(euler_zyz_matrix(phi, theta, psi), rotz(phi) @ roty(theta) @ rotz(psi))
    np.testing.assert_allclose(EulerZYZ(phi, theta, psi).matrix(), euler_zyz_matrix(phi, theta, psi))


def test_zyz_round_trip_both_branches_random():
    rng = np.random.default_rng(SEED)
    for _ in range(500):
        R = random_rotation(rng)
        sol = solve_euler_zyz(R)
        assert not sol.singular and len(sol.branches) == 2
        first, second = sol.branches
        assert 0.0 <= first.theta <= math.pi and -math.pi <= second.theta <= 0.0
        for b in sol.branches:
            np.testing.assert_allclose(b.matrix(), R, atol=1e-14)
            assert all(-math.pi < a <= math.pi for a in b.as_tuple())
        # Branch II = (phi + pi, -theta, psi + pi).
        assert wrap_angle(second.phi - first.phi - math.pi) == pytest.approx(0.0, abs=1e-12)
        assert second.theta == pytest.approx(-first.theta, abs=1e-15)
        assert wrap_angle(second.psi - first.psi - math.pi) == pytest.approx(0.0, abs=1e-12)


def test_zyz_recovers_generating_angles():
    rng = np.random.default_rng(SEED)
    for phi, theta, psi in zip(
        rng.uniform(-3.1, 3.1, 200), rng.uniform(0.01, 3.13, 200), rng.uniform(-3.1, 3.1, 200), strict=True
    ):
        sol = solve_euler_zyz(euler_zyz_matrix(phi, theta, psi))
        np.testing.assert_allclose(sol.branches[0].as_tuple(), (phi, theta, psi), atol=1e-12)


@pytest.mark.parametrize("theta", [0.0, math.pi])
def test_zyz_singular_cases_use_reference_phi(theta):
    phi, psi = 0.7, -1.2
    R = euler_zyz_matrix(phi, theta, psi)
    sol = solve_euler_zyz(R, reference_phi=-2.0)
    assert sol.singular and len(sol.branches) == 1
    b = sol.branches[0]
    assert b.phi == pytest.approx(-2.0)
    assert abs(b.theta) == pytest.approx(theta, abs=1e-15)
    np.testing.assert_allclose(b.matrix(), R, atol=1e-14)
    # Only phi + psi (theta = 0) or phi - psi (theta = pi) is defined.
    combo = (lambda e: e.phi + e.psi) if theta == 0.0 else (lambda e: e.phi - e.psi)
    assert wrap_angle(combo(b) - (phi + psi if theta == 0.0 else phi - psi)) == pytest.approx(0.0, abs=1e-14)


@pytest.mark.parametrize("theta", [1e-9, 1e-8, 1e-6, 3e-5, math.pi - 1e-7])
def test_zyz_near_singular_stays_exact(theta):
    R = euler_zyz_matrix(1.0, theta, -0.4)
    sol = solve_euler_zyz(R)
    assert not sol.singular
    for b in sol.branches:
        np.testing.assert_allclose(b.matrix(), R, atol=2e-15)


def test_zyz_inside_singular_tolerance_drops_only_the_tiny_tilt():
    """Within ``singular_tol`` phi is the reference: the error is at most ~2 sin(theta)."""
    R = euler_zyz_matrix(1.0, 1e-11, -0.4)
    sol = solve_euler_zyz(R, reference_phi=0.0)
    assert sol.singular
    assert np.max(np.abs(sol.branches[0].matrix() - R)) <= 2e-11


def test_zyz_rejects_non_rotations():
    with pytest.raises(RotationMatrixError, match="not a rotation"):
        solve_euler_zyz(np.diag([1.0, 1.0, 2.0]))
    with pytest.raises(RotationMatrixError, match="3x3"):
        solve_euler_zyz(np.eye(4))
    with pytest.raises(RotationMatrixError, match="finite"):
        solve_euler_zyz(np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="singular_tol"):
        solve_euler_zyz(np.eye(3), singular_tol=2.0)


def test_source_zyz_formula_2_68_typo():
    """Printed 2.68 ``phi_II = atan2(-r23, r13)`` fails the round trip; ``atan2(-r23, -r13)``
    (the listing of figure 3.4) passes."""
    rng = np.random.default_rng(SEED)
    failures = 0
    for _ in range(50):
        R = random_rotation(rng)
        r13, r23, r33 = R[0, 2], R[1, 2], R[2, 2]
        theta_ii = math.atan2(-math.hypot(r13, r23), r33)
        psi_ii = math.atan2(-R[2, 1], R[2, 0])
        printed = euler_zyz_matrix(math.atan2(-r23, r13), theta_ii, psi_ii)
        corrected = euler_zyz_matrix(math.atan2(-r23, -r13), theta_ii, psi_ii)
        np.testing.assert_allclose(corrected, R, atol=1e-14)
        failures += np.max(np.abs(printed - R)) > 1e-3
    assert failures >= 45  # fails unless r13 happens to be ~0


def test_wrap_angle():
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(-math.pi) == math.pi
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    np.testing.assert_allclose(wrap_angle(np.array([0.1, 7.0])), [0.1, 7.0 - 2 * math.pi])


@pytest.mark.parametrize("theta", [1e-11, -1e-11, 5e-11, math.pi - 1e-11, math.pi - 5e-11])
@pytest.mark.parametrize("phi, psi, reference", [(1.0, -0.4, 0.0), (2.0, -1.0, 0.0), (-3.0, 3.1, 0.0), (0.3, 0.5, 1.0)])
def test_zyz_singular_branch_sets_theta_exactly_and_drops_at_most_the_tilt(theta, phi, psi, reference):
    """Inside ``singular_tol`` theta is exactly 0 or π (only phi ± psi is defined) and the round trip
    misses ``R`` by at most the dropped tilt sin(theta) = sqrt(r13² + r23²), not twice it."""
    R = euler_zyz_matrix(phi, theta, psi)
    sol = solve_euler_zyz(R, reference_phi=reference)
    assert sol.singular and len(sol.branches) == 1
    b = sol.branches[0]
    assert b.theta == (0.0 if abs(theta) < 1.0 else math.pi)
    assert b.phi == reference
    assert np.max(np.abs(b.matrix() - R)) <= sol.sin_theta + 1e-15
