"""Closed-form 6R IK (planner.arm.analytic) and the source's worked example (figures 3.1-3.6).

Every number the source prints is first checked with forward kinematics (planner.arm.dh, itself
tested against closed forms in test_dh.py). A printed number passes when its FK agrees within
the rounding of the print: half a unit in the last digit of every printed angle, propagated
through the lever arms of the chain (``rounding_bound``), plus the rounding of the compared
printed quantity. Where a printed number fails, the test asserts that it fails and asserts the
verified value instead (docs/arm.md, "Errata").

Units: the source prints millimetres and degrees; the profile and the API are SI, so printed
lengths are multiplied by ``MM = 1e-3`` and printed angles by ``DEG = π/180``.
"""

import math

import numpy as np
import pytest

from planner.arm.analytic import (
    ArmStructureError,
    NoAdmissibleSolutionError,
    UnreachableTargetError,
    build_spherical_wrist_arm,
    select_nearest_solution,
    solve_arm_ik,
)
from planner.arm.dh import DHLink, build_dh_chain, forward_kinematics
from planner.arm.profile import load_arm_profile
from planner.arm.transforms import (
    ArmInputError,
    RotationMatrixError,
    homogeneous,
    invert_transform,
    nearest_rotation,
    rotation_distance,
    rotx,
    roty,
    rotz,
    wrap_angle,
)

MM, DEG = 1e-3, math.pi / 180
HALF_ULP = 0.5e-4  # half a unit in the 4th decimal (angles in deg, lengths in mm, matrix entries)
SEED = 20261126

# ----------------------------------------------------------------------------- printed numbers
P_TARGET_MM = np.array([100.0, 50.0, 120.0])  # (3.2), figure 3.1
R06_PRINTED = np.array([[-0.1219, -0.9917, 0.0406], [-0.1241, -0.0253, -0.9919], [0.9847, -0.1260, -0.1200]])
WC_PRINTED_MM = np.array([99.1880, 69.8380, 122.4000])  # figure 3.1
FIRST_PRINTED_DEG = np.array([35.1493, -12.4968, 74.2324, 63.4518, 111.1249, -147.4568])  # figure 3.4 "Or1 = 1x6"
V6_LISTING_DEG = -147.4508  # figure 3.4, the line "V6 = -147.4508" of the same listing
SECOND_WRIST_PRINTED_DEG = np.array([-116.5482, -111.1249, 32.5492])  # figure 3.4 "Or2 = 1x6"
ARM_PRINTED_DEG = {  # figure 3.2
    "Or1": np.array([35.1493, -12.4968, 74.2324]),
    "Or2": np.array([35.1493, 33.4209, -74.2324]),
    "Or3": np.array([-144.8507, -165.4658, 74.2324]),
    "Or4": np.array([-144.8507, 150.5704, -74.2324]),
}
R03_PRINTED = np.array([[0.3872, -0.7202, 0.5757], [0.2726, -0.5071, -0.8177], [0.8808, 0.4735, 0.0]])  # fig. 3.3
R36_PRINTED = np.array([[0.6170, 0.6674, 0.4169], [0.0313, -0.5502, 0.8344], [0.7863, -0.5019, -0.3604]])  # fig. 3.3
# Figure 3.6 (CAD model set to the first solution), 9 decimals; axes are printed as rows.
CAD_TOOL_ORIGIN_MM = np.array([99.999987887, 49.999179031, 119.999955725])
CAD_TOOL_AXES = np.array(
    [
        [-0.121938966, -0.124126689, 0.984745375],
        [-0.991706773, -0.025349718, -0.125996301],
        [0.040602521, -0.991942517, -0.120006159],
    ]
).T
CAD_WRIST_ORIGIN_MM = np.array([99.187937468, 89.838029370, 122.400078914])
CAD_WRIST_AXES = np.array(
    [
        [0.387193038, 0.272621848, 0.880771752],
        [-0.720167121, -0.507068237, 0.473541044],
        [0.575709014, -0.817654653, 0.000000000],
    ]
).T
CAD_HALF_ULP = 0.5e-9

# ----------------------------------------------------------------------------- verified values
#: The eight solutions, checked by forward kinematics below, to the source's 4 decimals [deg].
VERIFIED_DEG = {
    ("right", "down", "I"): (35.1493, -12.4968, 74.2324, 63.4518, 111.1249, -147.4508),
    ("right", "down", "II"): (35.1493, -12.4968, 74.2324, -116.5482, -111.1249, 32.5492),
    ("right", "up", "I"): (35.1493, 33.4209, -74.2324, 117.9296, 109.1877, -35.0533),
    ("right", "up", "II"): (35.1493, 33.4209, -74.2324, -62.0704, -109.1877, 144.9467),
    ("left", "up", "I"): (-144.8507, 146.5791, 74.2324, -62.0704, 109.1877, -35.0533),
    ("left", "up", "II"): (-144.8507, 146.5791, 74.2324, 117.9296, -109.1877, 144.9467),
    ("left", "down", "I"): (-144.8507, -167.5032, -74.2324, -116.5482, 111.1249, -147.4508),
    ("left", "down", "II"): (-144.8507, -167.5032, -74.2324, 63.4518, -111.1249, 32.5492),
}
#: The source's three-link frame 3 is DH frame 3 times (rotx(π/2) roty(π/2))ᵀ (figure 3.3).
M_WRIST = rotx(math.pi / 2) @ roty(math.pi / 2)


@pytest.fixture(scope="module")
def arm():
    return build_spherical_wrist_arm(load_arm_profile("arm-source-example").chain())


def fk(arm, q_deg):
    return forward_kinematics(arm.chain, np.asarray(q_deg, dtype=float) * DEG)


def rounding_bound(frames, point, joints, step=HALF_ULP * DEG):
    """How far ``point`` [m] can move when each joint in ``joints`` (1-based) moves by ``step``."""
    return sum(
        np.linalg.norm(np.cross(frames.frames[j - 1][:3, 2], point - frames.origin(j - 1))) * step for j in joints
    )


def solutions_by_label(result):
    return {(s.shoulder, s.elbow, s.wrist): s for s in result.solutions}


# ============================================================================= worked example
def test_profile_lengths_are_the_source_numbers_in_metres(arm):
    assert (arm.d1, arm.a2, arm.d4, arm.d6) == (100 * MM, 100 * MM, 50 * MM, 20 * MM)
    assert arm.offsets == (0.0, 0.0, math.pi / 2, 0.0, 0.0, 0.0)


def test_wrist_centre(arm):
    """Printed (99.1880, 69.8380, 122.4000) = target - 20 · R06[:, 2] with the printed matrix."""
    raw = solve_arm_ik(arm, P_TARGET_MM * MM, R06_PRINTED, orthonormalize=False)
    np.testing.assert_allclose(raw.wrist_centre / MM, WC_PRINTED_MM, atol=1e-4)
    # FK check: frame 4's origin at the printed first arm posture.
    fr = fk(arm, FIRST_PRINTED_DEG)
    wc = fr.origin(4)
    tol = rounding_bound(fr, wc, (1, 2, 3)) + math.sqrt(3) * HALF_ULP * MM
    assert np.linalg.norm(wc - WC_PRINTED_MM * MM) <= tol
    # The projected target moves the wrist centre by at most d6 · (entry change of column 3).
    proj = solve_arm_ik(arm, P_TARGET_MM * MM, R06_PRINTED)
    shift = np.linalg.norm(proj.wrist_centre - raw.wrist_centre)
    assert shift <= arm.d6 * math.sqrt(3) * proj.projection_change
    assert 1e-4 * MM < shift  # large enough that the print is only reproduced without projection


def test_arm_postures_two_printed_ones_are_wrong(arm):
    """Or1 and Or2 put the wrist centre where it must be; Or3 and Or4 miss it by ~90-100 mm."""
    fr1 = fk(arm, np.r_[ARM_PRINTED_DEG["Or1"], 0, 0, 0])
    tol = rounding_bound(fr1, fr1.origin(4), (1, 2, 3)) + math.sqrt(3) * HALF_ULP * MM
    misses = {}
    for name, arm_deg in ARM_PRINTED_DEG.items():
        fr = fk(arm, np.r_[arm_deg, 0, 0, 0])
        misses[name] = np.linalg.norm(fr.origin(4) - WC_PRINTED_MM * MM)
    assert misses["Or1"] <= tol and misses["Or2"] <= tol
    assert misses["Or3"] > 80 * MM and misses["Or4"] > 80 * MM  # > 10^5 × tol
    # The verified postures pass the same check.
    for key in (("left", "up", "I"), ("left", "down", "I")):
        fr = fk(arm, VERIFIED_DEG[key])
        assert np.linalg.norm(fr.origin(4) - WC_PRINTED_MM * MM) <= tol


def test_arm_posture_errata_come_from_the_listing_sine_sign(arm):
    """Figure 3.2 computes V2ii and V2iv with the sine numerator of the right shoulder,
    (a2 + a3 c3) pwz ∓ a3 s3 r: with it the printed -165.4658 and 150.5704 come out; the
    left shoulder needs the opposite sign (verified 146.5791 and -167.5032)."""
    a2, a3 = 100.0, 50.0
    pwx, pwy, pwz = WC_PRINTED_MM - [0, 0, 100.0]
    r = math.hypot(pwx, pwy)
    c3 = (pwx**2 + pwy**2 + pwz**2 - a2**2 - a3**2) / (2 * a2 * a3)
    s3 = math.sqrt(1 - c3**2)
    k = a2 + a3 * c3
    listing_v2ii = math.degrees(math.atan2(k * pwz - a3 * s3 * r, -k * r + pwz * a3 * s3))
    listing_v2iv = math.degrees(math.atan2(pwz * k + r * a3 * s3, -r * k - pwz * a3 * s3))
    assert listing_v2ii == pytest.approx(ARM_PRINTED_DEG["Or3"][1], abs=HALF_ULP)
    assert listing_v2iv == pytest.approx(ARM_PRINTED_DEG["Or4"][1], abs=HALF_ULP)
    fixed_v2ii = math.degrees(math.atan2(k * pwz + a3 * s3 * r, -k * r + pwz * a3 * s3))
    fixed_v2iv = math.degrees(math.atan2(pwz * k - r * a3 * s3, -r * k - pwz * a3 * s3))
    assert fixed_v2ii == pytest.approx(VERIFIED_DEG[("left", "up", "I")][1], abs=HALF_ULP)
    assert fixed_v2iv == pytest.approx(VERIFIED_DEG[("left", "down", "I")][1], abs=HALF_ULP)


def test_typeset_theta2_formulas_2_52_to_2_55():
    """2.52 and 2.54 (right shoulder) are right (reading "p_Wz 3 s3" as p_Wz a3 s3); 2.53 and
    2.55 (left shoulder) lack the minus of the cosine argument and 2.55 has the wrong sine sign."""
    a2, a3 = 100.0, 50.0
    pwx, pwy, pwz = WC_PRINTED_MM - [0, 0, 100.0]
    r = math.hypot(pwx, pwy)
    c3 = (r * r + pwz * pwz - a2 * a2 - a3 * a3) / (2 * a2 * a3)
    sp = math.sqrt(1 - c3 * c3)
    sm, k = -sp, a2 + a3 * c3
    deg = math.degrees
    verified = {key[:2]: VERIFIED_DEG[key][1] for key in VERIFIED_DEG}
    assert deg(math.atan2(pwz * k - a3 * sp * r, r * k + pwz * a3 * sp)) == pytest.approx(
        verified[("right", "down")], abs=HALF_ULP
    )
    assert deg(math.atan2(pwz * k + a3 * sp * r, r * k + pwz * a3 * sm)) == pytest.approx(
        verified[("right", "up")], abs=HALF_ULP
    )
    printed_253 = deg(math.atan2(pwz * k + a3 * sp * r, r * k + pwz * a3 * sp))
    printed_255 = deg(math.atan2(pwz * k - a3 * sm * r, r * k + pwz * a3 * sm))
    assert abs(printed_253 - verified[("left", "up")]) > 100 and abs(printed_255 - verified[("left", "down")]) > 100
    fixed_253 = deg(math.atan2(pwz * k + a3 * sp * r, -r * k + pwz * a3 * sp))
    fixed_255 = deg(math.atan2(pwz * k + a3 * sm * r, -r * k + pwz * a3 * sm))
    assert fixed_253 == pytest.approx(verified[("left", "up")], abs=HALF_ULP)
    assert fixed_255 == pytest.approx(verified[("left", "down")], abs=HALF_ULP)


def test_theta6_of_the_first_solution_is_a_typo(arm):
    """Or1 prints θ6 = -147.4568, the listing line above it -147.4508.

    FK checks: (1) the two printed wrist solutions must give the same tool frame; with -147.4568
    they differ by 1e-4 rad, 20× what rounding allows. (2) The CAD model of figure 3.6 was set
    to the first solution; its tool frame matches -147.4508 to 1e-9 and misses -147.4568.
    (3) Against the printed R06 (4 decimals) -147.4568 also fails, by a smaller margin."""
    printed, fixed = FIRST_PRINTED_DEG.copy(), FIRST_PRINTED_DEG.copy()
    fixed[5] = V6_LISTING_DEG
    second = np.r_[FIRST_PRINTED_DEG[:3], SECOND_WRIST_PRINTED_DEG]
    R_printed, R_fixed, R_second = (fk(arm, q).rotation for q in (printed, fixed, second))
    branch_tol = 2 * 3 * HALF_ULP * DEG  # two solutions × three rounded wrist angles, unit rates
    assert rotation_distance(R_printed, R_second) > 15 * branch_tol
    assert rotation_distance(R_fixed, R_second) <= branch_tol
    cad_tol = 6 * HALF_ULP * DEG + CAD_HALF_ULP
    assert np.max(np.abs(R_printed - CAD_TOOL_AXES)) > 15 * cad_tol
    assert np.max(np.abs(R_fixed - CAD_TOOL_AXES)) <= cad_tol
    entry_tol = HALF_ULP + 6 * HALF_ULP * DEG
    assert np.max(np.abs(R_printed - R06_PRINTED)) > 1.5 * entry_tol
    assert np.max(np.abs(R_fixed - R06_PRINTED)) <= entry_tol
    assert np.max(np.abs(R_second - R06_PRINTED)) <= entry_tol


def test_tool_position_of_the_first_solution(arm):
    fr = fk(arm, VERIFIED_DEG[("right", "down", "I")])
    p = fr.position
    lever = rounding_bound(fr, p, range(1, 7))
    assert np.linalg.norm(p - CAD_TOOL_ORIGIN_MM * MM) <= lever + math.sqrt(3) * CAD_HALF_ULP * MM
    # Against (100, 50, 120): plus the tool length times the print rounding of R06[:, 2].
    assert np.linalg.norm(p - P_TARGET_MM * MM) <= lever + arm.d6 * math.sqrt(3) * HALF_ULP


def test_intermediate_matrices_and_cad_wrist_frame(arm):
    """R03 (figure 3.3) and the CAD wrist frame pass; the CAD wrist origin's y is a typo:
    89.838029370 printed, 69.838029 by FK (x and z agree to 1e-6 mm)."""
    fr = fk(arm, VERIFIED_DEG[("right", "down", "I")])
    R03_source = fr.frames[3][:3, :3] @ M_WRIST.T
    tol3 = 3 * HALF_ULP * DEG
    assert np.max(np.abs(R03_source - R03_PRINTED)) <= HALF_ULP + tol3
    assert np.max(np.abs(R03_source - CAD_WRIST_AXES)) <= CAD_HALF_ULP + tol3
    wc = fr.origin(4)
    bound = rounding_bound(fr, wc, (1, 2, 3)) + CAD_HALF_ULP * MM
    err = np.abs(wc - CAD_WRIST_ORIGIN_MM * MM)
    assert err[0] <= bound and err[2] <= bound
    assert err[1] == pytest.approx(20.0 * MM, abs=bound)
    assert wc[1] / MM == pytest.approx(69.838029370, abs=bound / MM)
    # R36 (figure 3.3) is the source's arithmetic (R03 · M)ᵀ · R06 on the printed R06.
    np.testing.assert_allclose((fr.frames[3][:3, :3]).T @ R06_PRINTED, R36_PRINTED, atol=HALF_ULP + tol3)


def test_source_arithmetic_reproduces_every_verified_number(arm):
    """Without projection (the source's arithmetic on its 4-decimal R06) the solver reproduces
    the printed numbers that passed the FK checks, and the verified values of the others."""
    res = solve_arm_ik(arm, P_TARGET_MM * MM, R06_PRINTED, orthonormalize=False)
    assert res.reachable and len(res.solutions) == 8
    by = solutions_by_label(res)
    assert set(by) == set(VERIFIED_DEG)
    for key, want in VERIFIED_DEG.items():
        np.testing.assert_allclose(np.degrees(by[key].joints), want, atol=1e-4, err_msg=str(key))
    first = np.degrees(by[("right", "down", "I")].joints)
    np.testing.assert_allclose(first[:5], FIRST_PRINTED_DEG[:5], atol=1e-4)
    assert abs(first[5] - FIRST_PRINTED_DEG[5]) > 50 * HALF_ULP  # the θ6 typo
    np.testing.assert_allclose(np.degrees(by[("right", "down", "II")].joints[3:]), SECOND_WRIST_PRINTED_DEG, atol=1e-4)
    np.testing.assert_allclose(np.degrees(by[("right", "up", "I")].joints[:3]), ARM_PRINTED_DEG["Or2"], atol=1e-4)
    for name, key in (("Or3", ("left", "up", "I")), ("Or4", ("left", "down", "I"))):
        assert np.max(np.abs(np.degrees(by[key].joints[:3]) - ARM_PRINTED_DEG[name])) > 10.0


def test_every_verified_solution_passes_forward_kinematics(arm):
    """All eight verified rows, rounded to 4 decimals, reach the target within the rounding of
    the angles and of the printed R06 (which is ~1e-4 from orthonormal)."""
    R_proj = nearest_rotation(R06_PRINTED)
    rot_tol = 6 * HALF_ULP * DEG + 2 * np.linalg.norm(R06_PRINTED - R_proj)
    for key, q_deg in VERIFIED_DEG.items():
        fr = fk(arm, q_deg)
        pos_tol = rounding_bound(fr, fr.position, range(1, 7)) + arm.d6 * math.sqrt(3) * HALF_ULP
        assert np.linalg.norm(fr.position - P_TARGET_MM * MM) <= pos_tol, key
        assert rotation_distance(fr.rotation, R_proj) <= rot_tol, key


def test_product_solver_projects_and_is_exact(arm):
    """Default path: R06 projected onto SO(3) (entries change < 5e-5, so the print still stands
    for it); all eight solutions reach the projected target to 1e-9 and differ from the
    source-arithmetic ones by less than 0.005° (measured ~0.002°)."""
    res = solve_arm_ik(arm, P_TARGET_MM * MM, R06_PRINTED)
    raw = solutions_by_label(solve_arm_ik(arm, P_TARGET_MM * MM, R06_PRINTED, orthonormalize=False))
    assert 5e-5 < res.rotation_defect < 2e-4 and res.projection_change < HALF_ULP
    assert len(res.solutions) == 8
    for s in res.solutions:
        fr = forward_kinematics(arm.chain, s.joints)
        assert np.linalg.norm(fr.position - P_TARGET_MM * MM) <= 1e-9
        assert rotation_distance(fr.rotation, res.rotation) <= 1e-9
        assert s.position_error <= 1e-12 and s.rotation_error <= 1e-12 and s.within_limits
        diff = np.abs(np.degrees(wrap_angle(np.array(s.joints) - raw[(s.shoulder, s.elbow, s.wrist)].joints)))
        assert np.max(diff) < 0.005


# ============================================================================= random poses
def random_targets(chain, rng, n):
    for q in rng.uniform(chain.lower, chain.upper, size=(n, chain.n)):
        fr = forward_kinematics(chain, q)
        yield q, fr.position, fr.rotation


def check_random(arm, rng, n):
    worst_p = worst_r = worst_q = 0.0
    to0 = invert_transform(arm.chain.base)
    for q, p, R in random_targets(arm.chain, rng, n):
        res = solve_arm_ik(arm, p, R)
        assert res.reachable and len(res.solutions) == 8
        gaps = []
        for s in res.solutions:
            fr = forward_kinematics(arm.chain, s.joints)
            worst_p = max(worst_p, np.linalg.norm(fr.position - p))
            worst_r = max(worst_r, rotation_distance(fr.rotation, R))
            gaps.append(np.max(np.abs(wrap_angle(np.array(s.joints) - q))))
            # Geometric labels in frame 0: elbow (frame 2 origin) above/below the line from the
            # shoulder (frame 1 origin) to the wrist centre; arm plane facing the wrist centre.
            sh, el, wc = ((to0 @ np.append(fr.origin(i), 1.0))[:3] for i in (1, 2, 4))
            u = wc - sh
            h = np.array([u[0], u[1], 0.0])
            if np.linalg.norm(h) > 1e-6 and abs(np.cross(u, el - sh) @ np.cross(h, [0, 0, 1])) > 1e-9:
                above = np.cross(u, el - sh) @ np.cross(h, [0, 0, 1]) > 0
                assert (s.elbow == "up") == above
            facing = np.array([math.cos(s.joints[0] + arm.offsets[0]), math.sin(s.joints[0] + arm.offsets[0])]) @ h[:2]
            assert (s.shoulder == "right") == (facing > 0)
        worst_q = max(worst_q, min(gaps))
    return worst_p, worst_r, worst_q


def test_1000_random_poses_of_the_source_arm(arm):
    worst_p, worst_r, worst_q = check_random(arm, np.random.default_rng(SEED), 1000)
    assert worst_p <= 1e-9 and worst_r <= 1e-9  # every solution
    assert worst_q <= 1e-8  # the generating joints are among the solutions


def test_random_poses_general_arm_with_offsets_base_and_tool():
    h = math.pi / 2
    links = [
        DHLink(0, h, 0.45, 0.3),
        DHLink(1.2, 0, 0, -0.7),
        DHLink(0, h, 0, 2.0),
        DHLink(0, -h, 0.9, 0.1),
        DHLink(0, h, 0, -0.4),
        DHLink(0, 0, 0.25, 1.1),
    ]
    base = homogeneous(rotz(0.6) @ roty(0.2), [1.0, -0.5, 0.3])
    tool = homogeneous(rotx(0.3), [0.02, -0.01, 0.15])
    arm = build_spherical_wrist_arm(build_dh_chain(links, base=base, tool=tool))
    worst_p, worst_r, worst_q = check_random(arm, np.random.default_rng(SEED + 1), 300)
    assert worst_p <= 1e-9 and worst_r <= 1e-9 and worst_q <= 1e-8


# ============================================================================= edge cases
def test_unreachable_targets_are_reported(arm):
    R = np.eye(3)
    far = solve_arm_ik(arm, [0.5, 0.0, 0.1], R)
    assert not far.reachable and far.solutions == () and "too far" in far.reason
    assert "[0.05, 0.15] m" in far.reason and far.cos_elbow > 1
    # Wrist centre 1 cm above the shoulder: nearer than |a2 - d4| = 5 cm.
    near = solve_arm_ik(arm, [0.0, 0.0, 0.1 + 0.01 + arm.d6], R)
    assert not near.reachable and "too close" in near.reason and near.cos_elbow < -1
    for res in (far, near):
        assert np.all(np.isfinite(res.wrist_centre)) and math.isfinite(res.cos_elbow)
        with pytest.raises(UnreachableTargetError, match="unreachable"):
            select_nearest_solution(arm, res, np.zeros(6))


def test_fully_stretched_arm_is_reachable(arm):
    q = np.array([0.3, 0.2, 0.0, 0.4, 0.9, -0.2])  # q3 = 0: forearm in line with the upper arm
    fr = forward_kinematics(arm.chain, q)
    res = solve_arm_ik(arm, fr.position, fr.rotation)
    assert res.reachable and res.elbow_singular
    assert all(s.position_error < 1e-12 and s.rotation_error < 1e-12 for s in res.solutions)


def test_shoulder_singularity_uses_the_reference(arm):
    q2 = 1.2
    q3 = math.acos(-2.0 * math.cos(q2)) - q2  # a2 cos q2 + d4 cos(q2 + q3) = 0: wrist on the z0 axis
    q = np.array([0.9, q2, q3, 0.3, -0.8, 0.5])
    fr = forward_kinematics(arm.chain, q)
    ref = np.array([0.4, 0, 0, 0, 0, 0])
    res = solve_arm_ik(arm, fr.position, fr.rotation, reference=ref)
    assert res.shoulder_singular
    assert all(s.position_error < 1e-12 and s.rotation_error < 1e-12 for s in res.solutions)
    assert {round(s.joints[0], 12) for s in res.solutions} == {0.4, round(0.4 - math.pi, 12)}


def test_wrist_singularity_uses_the_reference(arm):
    q = np.array([0.5, -0.3, 1.1, 0.7, 0.0, -0.9])
    fr = forward_kinematics(arm.chain, q)
    res = solve_arm_ik(arm, fr.position, fr.rotation, reference=[0, 0, 0, 0.25, 0, 0])
    # θ5 = 0 in this posture and in its mirror (left/down shares R03's wrist axis): one wrist
    # solution each; the other two postures need a non-singular wrist (two solutions each).
    assert len(res.solutions) == 6
    assert sorted(s.label for s in res.solutions if s.wrist_singular) == ["left/down/I", "right/down/I"]
    right_down = [s for s in res.solutions if s.shoulder == "right" and s.elbow == "down"]
    assert len(right_down) == 1 and right_down[0].wrist_singular
    assert right_down[0].joints[3] == pytest.approx(0.25)
    assert right_down[0].joints[3] + right_down[0].joints[5] == pytest.approx(q[3] + q[5])
    assert all(s.position_error < 1e-12 and s.rotation_error < 1e-12 for s in res.solutions)


# ============================================================================= selection and limits
def limited_arm(limits):
    base = load_arm_profile().chain()
    links = [
        DHLink(k.a, k.alpha, k.d, k.theta, k.kind, lo, hi, k.name)
        for k, (lo, hi) in zip(base.links, limits, strict=True)
    ]
    return build_spherical_wrist_arm(build_dh_chain(links))


def test_nearest_solution_is_the_generating_posture(arm):
    rng = np.random.default_rng(SEED)
    for q, p, R in random_targets(arm.chain, rng, 50):
        res = solve_arm_ik(arm, p, R)
        best = select_nearest_solution(arm, res, q)
        assert np.max(np.abs(np.array(best.joints) - q)) < 1e-8


def test_selection_respects_limits_and_minimises_distance():
    pi = math.pi
    arm = limited_arm([(-pi, pi), (-1.0, 1.5), (-pi, pi), (-pi, pi), (0.05, pi), (0.0, 2 * pi)])
    rng = np.random.default_rng(SEED)
    checked = 0
    for _, p, R in random_targets(arm.chain, rng, 200):
        res = solve_arm_ik(arm, p, R)
        ref = rng.uniform(-2, 2, 6)
        # Independent brute force over every 2π-equivalent of every solution.
        best_cost, feasible = math.inf, False
        for s in res.solutions:
            options = []
            for x, lo, hi, r in zip(s.joints, arm.chain.lower, arm.chain.upper, ref, strict=True):
                cands = [x + 2 * pi * k for k in range(-3, 4) if lo - 1e-12 <= x + 2 * pi * k <= hi + 1e-12]
                options.append(min((c - r) ** 2 for c in cands) if cands else None)
            if None not in options:
                feasible = True
                best_cost = min(best_cost, sum(options))
        assert feasible == bool(res.admissible)
        if not feasible:
            with pytest.raises(NoAdmissibleSolutionError, match="no analytic solution within the joint limits"):
                select_nearest_solution(arm, res, ref)
            continue
        best = select_nearest_solution(arm, res, ref)
        j = np.array(best.joints)
        assert np.all(j >= arm.chain.lower - 1e-12) and np.all(j <= arm.chain.upper + 1e-12)
        assert float(np.sum((j - ref) ** 2)) == pytest.approx(best_cost, abs=1e-9)
        fr = forward_kinematics(arm.chain, j)
        assert np.linalg.norm(fr.position - p) < 1e-12 and rotation_distance(fr.rotation, R) < 1e-12
        checked += 1
    assert checked > 100


def test_joints_are_reported_inside_limits_that_do_not_contain_zero():
    arm = limited_arm([(-math.pi, math.pi)] * 5 + [(0.5, 6.2)])
    q = np.array([0.1, 0.2, 0.3, 0.4, 0.5, -1.0])  # -1.0 ≡ 5.283 rad
    fr = forward_kinematics(arm.chain, q)
    res = solve_arm_ik(arm, fr.position, fr.rotation)
    assert all(s.within_limits and 0.5 <= s.joints[5] <= 6.2 for s in res.solutions)
    best = select_nearest_solution(arm, res, [0.1, 0.2, 0.3, 0.4, 0.5, 5.0])
    assert best.joints[5] == pytest.approx(2 * math.pi - 1.0)


# ============================================================================= bad input
def test_structure_is_checked():
    chain = load_arm_profile().chain()
    links = list(chain.links)
    with pytest.raises(ArmStructureError, match="6 joints"):
        build_spherical_wrist_arm(build_dh_chain(links[:5]))
    bad = links.copy()
    bad[2] = DHLink(0.05, math.pi / 2, 0, 0, name="elbow")
    with pytest.raises(ArmStructureError, match=r"links\[2\] \(elbow\)\.a = 0\.05 m; required: 0"):
        build_spherical_wrist_arm(build_dh_chain(bad))
    bad = links.copy()
    bad[4] = DHLink(0, -math.pi / 2, 0, 0, name="wrist_bend")
    with pytest.raises(ArmStructureError, match=r"wrist_bend\)\.alpha"):
        build_spherical_wrist_arm(build_dh_chain(bad))
    bad = links.copy()
    bad[0] = DHLink(0, math.pi / 2, 0.1, 0, kind="prismatic", lower=0, upper=1, name="lift")
    with pytest.raises(ArmStructureError, match="required: 'revolute'"):
        build_spherical_wrist_arm(build_dh_chain(bad))
    bad = links.copy()
    bad[3] = DHLink(0, -math.pi / 2, 0.0, 0, name="forearm_roll")
    with pytest.raises(ArmStructureError, match=r"\.d = 0\.0 m; required: > 0"):
        build_spherical_wrist_arm(build_dh_chain(bad))


def test_bad_targets_are_named(arm):
    with pytest.raises(ValueError, match="position must be 3 finite numbers"):
        solve_arm_ik(arm, [0.1, float("nan"), 0.1], np.eye(3))
    with pytest.raises(ValueError, match="position must be 3"):
        solve_arm_ik(arm, [0.1, 0.1], np.eye(3))
    with pytest.raises(RotationMatrixError, match=r"rotation is not a rotation matrix.*allowed: <= 0\.001"):
        solve_arm_ik(arm, [0.1, 0.0, 0.1], np.diag([1.0, 1.0, 1.01]))
    with pytest.raises(RotationMatrixError, match="det"):
        solve_arm_ik(arm, [0.1, 0.0, 0.1], -np.eye(3))
    with pytest.raises(ValueError, match="reference must have 6 joint values"):
        solve_arm_ik(arm, [0.1, 0.0, 0.1], np.eye(3), reference=[0.0])
    res = solve_arm_ik(arm, [0.1, 0.0, 0.1], np.eye(3))
    with pytest.raises(ValueError, match="weights must be >= 0"):
        select_nearest_solution(arm, res, np.zeros(6), weights=[1, 1, 1, 1, 1, -1])


# --------------------------------------------------------------------------- unit slips, bad options
def test_target_in_millimetres_gets_a_hint(arm):
    R = forward_kinematics(arm.chain, [0.6135, -0.2181, 1.2956, 1.1074, 1.9395, -2.5735]).rotation
    res = solve_arm_ik(arm, [100, 50, 120], R)
    assert not res.reachable and res.solutions == ()
    assert "too far from it; reachable distances are [0.05, 0.15] m" in res.reason
    assert res.reason.endswith("; did you mean mm? position (100, 50, 120) mm = (0.1, 0.05, 0.12) m is reachable")
    with pytest.raises(UnreachableTargetError, match=r"did you mean mm\?"):
        select_nearest_solution(arm, res, np.zeros(6))
    # a target out of reach in metres too gets no hint
    far = solve_arm_ik(arm, [1.0, 0.0, 0.5], np.eye(3))
    assert not far.reachable and "did you mean" not in far.reason


@pytest.mark.parametrize("tol", [float("nan"), -1.0, 0.0, float("inf"), 0.5, True, "1e-3"])
def test_rotation_tol_is_checked(arm, tol):
    with pytest.raises(ArmInputError, match=r"rotation_tol"):
        solve_arm_ik(arm, [0.1, 0.05, 0.12], np.eye(3), rotation_tol=tol)


def test_reference_in_degrees_is_refused(arm):
    p, R = [0.1, 0.05, 0.12], np.eye(3)
    ref_deg = [35.1493, -12.4968, 74.2324, 63.4518, 111.1249, -147.4508]
    with pytest.raises(ArmInputError, match=r"reference\[0\] \(waist\) = 35\.1493 rad .*did you mean degrees\?"):
        solve_arm_ik(arm, p, R, reference=ref_deg)
    res = solve_arm_ik(arm, p, R)
    with pytest.raises(ArmInputError, match=r"reference\[2\] \(elbow\) = 74\.2324 rad .*did you mean degrees\?"):
        select_nearest_solution(arm, res, [0.6, -0.2, 74.2324, 1.1, 1.9, -2.6])
    # weights are no angles: large weights stay allowed
    select_nearest_solution(arm, res, np.zeros(6), weights=[100.0] * 6)
