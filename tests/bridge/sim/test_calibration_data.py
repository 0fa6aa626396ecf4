"""The physical evaluation of a profile on the twin: whole counts, the piston inside its count, pin play."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from bridge.sim.calibration_data import APPROACH_OFFSET, measure_twin, true_poses
from bridge.sim.truth import MachineTruth, PinPlay, TrueMachine, TruthError
from planner.calibration.design import candidate_poses
from planner.calibration.parametric import ParametricModel
from planner.model.kinematics import HitchModel
from planner.profiles.hitch import load_profile


@pytest.fixture(scope="module")
def setup():
    prof = load_profile("thesis-t132")
    poses, _ = candidate_poses(ParametricModel(prof), 24, seed=7)
    return prof, HitchModel(prof), poses[:6]


def _box_of_pose(truth: MachineTruth, model: HitchModel, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per DOF, the range of the true pose over the 32 corners of the ± 0.5-count box about ``counts``."""
    corners = []
    for signs in itertools.product((-0.5, 0.5), repeat=5):
        corners.append(TrueMachine(truth, model.category).observe(counts + np.array(signs)).controlled())
    c = np.array(corners)
    return c.min(axis=0), c.max(axis=0)


def test_quantised_and_dithered_pose_lies_in_the_image_of_the_count_band(setup):
    prof, model, poses = setup
    truth = MachineTruth.nominal(prof)
    exact, _ = true_poses(model, truth, poses)
    whole, counts_w = true_poses(model, truth, poses, quantise=True)
    dith, counts_d = true_poses(model, truth, poses, quantise=True, dither=True, seed=3)
    assert np.all(counts_d == np.rint(counts_d)) and np.array_equal(counts_d, counts_w)
    # the piston moved inside its count: the pose differs from the one at the whole counts ...
    assert np.all(np.abs(dith - whole).max(axis=1) > 1e-6)
    for k in range(len(poses)):  # ... but stays within what the ± 0.5-count box reaches (small slack: curvature)
        lo, hi = _box_of_pose(truth, model, counts_d[k])
        slack = np.array([1e-5, 1e-5, 1e-5, 1e-5])
        assert np.all(dith[k] >= lo - slack) and np.all(dith[k] <= hi + slack)
        assert np.all(exact[k] >= lo - slack) and np.all(exact[k] <= hi + slack)


def test_dither_is_seeded_and_spreads_over_the_band(setup):
    prof, model, poses = setup
    truth = MachineTruth.nominal(prof)
    a, _ = true_poses(model, truth, poses, quantise=True, dither=True, seed=11)
    b, _ = true_poses(model, truth, poses, quantise=True, dither=True, seed=11)
    c, _ = true_poses(model, truth, poses, quantise=True, dither=True, seed=12)
    assert np.array_equal(a, b) and not np.allclose(a, c)


def test_random_approach_lags_by_the_full_play_band_on_both_sides(setup):
    prof, model, poses = setup
    play = PinPlay(0.0008, 0.0006)
    truth = MachineTruth(prof, play)
    centred, _ = true_poses(model, truth, poses)
    lagged, _ = true_poses(model, truth, poses, play="random", seed=5)
    cat = prof.category(model.category)
    band = np.array(
        [
            play.lower_link_m,
            play.lower_link_m,
            2.0 * play.lower_link_m / prof.span(model.category),
            (play.lower_link_m + play.top_link_m) / cat.mast_height,
        ]
    )
    assert np.all(APPROACH_OFFSET > 2.0 * band)  # the approach starts beyond the dead band
    lag = lagged - centred
    assert np.allclose(np.abs(lag), band, rtol=0.02, atol=2e-6)
    signs = np.sign(lag)
    assert np.any(signs > 0) and np.any(signs < 0)  # random sides, not always from below
    assert np.allclose(centred, true_poses(model, MachineTruth(prof), poses)[0], atol=1e-9)  # centred: no lag


def test_defaults_are_the_idealised_evaluation(setup):
    prof, model, poses = setup
    truth = MachineTruth(prof, PinPlay(0.001, 0.001))
    a, ca = true_poses(model, truth, poses)
    b, cb = true_poses(model, truth, poses, quantise=False, dither=False, play="centred", seed=99)
    assert np.array_equal(a, b) and np.array_equal(ca, cb)
    assert not np.all(ca == np.rint(ca))  # unrounded counts


def test_measure_twin_dither_moves_the_piston_not_the_reading(setup):
    prof, model, poses = setup
    truth = MachineTruth.nominal(prof)
    plain = measure_twin(model, truth, poses[:3], noise="none", approach="direct")
    dith = measure_twin(model, truth, poses[:3], noise="none", approach="direct", dither=True, seed=4)
    assert np.array_equal(plain.counts, dith.counts) and np.all(dith.counts == np.rint(dith.counts))
    rows = [0, 2, 3, 4]  # x, z, roll, pitch
    assert not np.allclose(plain.true[:, rows], dith.true[:, rows], atol=1e-7)
    assert np.allclose(dith.measured[:, rows], dith.true[:, rows])


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"dither": True}, "dither"),
        ({"quantise": 1}, "quantise"),
        ({"play": "left"}, "play"),
        ({"seed": -1}, "seed"),
    ],
)
def test_bad_evaluation_options_name_the_field(setup, kwargs, field):
    prof, model, poses = setup
    with pytest.raises(TruthError, match=field):
        true_poses(model, MachineTruth.nominal(prof), poses[:1], **kwargs)


def test_measure_twin_rejects_a_non_bool_dither(setup):
    prof, model, poses = setup
    with pytest.raises(TruthError, match="dither"):
        measure_twin(model, MachineTruth.nominal(prof), poses[:1], dither="yes")  # type: ignore[arg-type]


def test_measuring_by_goto_reads_where_the_twin_s_real_gotos_leave_the_implement(setup):
    """The operator's procedure on the running twin: one row per pose, readings = the link's whole counts at
    rest, the instrument reading the true pose and points (exactly, without noise); the pistons stop inside
    their counts where the ECU leaves them, so the true pose is within the count box of the readings."""
    prof, model, poses = setup
    truth = MachineTruth(prof, PinPlay())
    data = measure_twin(model, truth, poses[:3], noise="none", points=("L", "U"), by="goto")
    assert data.counts.shape == (3, 5) and np.all(data.counts == np.round(data.counts))
    pose_cols = [0, 2, 3, 4]  # MEASURED_COLUMNS: x, y, z, roll, pitch, yaw, points
    assert np.allclose(data.measured[:, pose_cols], data.true[:, pose_cols], atol=1e-12)
    assert np.all(np.isfinite(data.measured[:, pose_cols])) and np.isfinite(data.measured).sum() == 3 * (4 + 6)
    for k in range(3):
        lo, hi = _box_of_pose(truth, model, data.counts[k])
        assert np.all(data.true[k, pose_cols] >= lo - 1e-9) and np.all(data.true[k, pose_cols] <= hi + 1e-9)
        assert np.max(np.abs(data.true[k, pose_cols] - poses[k])) < 0.004  # a count or so from the commanded pose
    with pytest.raises(TruthError, match="by must be static or goto"):
        measure_twin(model, truth, poses[:1], by="teleport")


def test_measuring_by_goto_from_both_sides_leaves_the_play_taken_up_on_each_side(tmp_path):
    """--sides both: a pass with the profile's final approach (from below) and one with its mirror image (from
    above); every row names its side, and the twin's true implement lags its true mechanism on that side by
    most of the play's band in every DOF (with the count approach: its count step can move another DOF back a
    little into the dead band)."""
    from tests.helpers import profile_file_with_final_approach

    prof = load_profile(profile_file_with_final_approach(tmp_path, count_approach=True))
    model = HitchModel(prof)
    truth = MachineTruth(load_profile("thesis-t132"), PinPlay(0.001, 0.0005))
    band = TrueMachine(truth, model.category).band
    poses, _ = candidate_poses(ParametricModel(prof), 24, seed=7, two_sided=True)
    data = measure_twin(model, truth, poses[:3], noise="none", by="goto", approach="both")
    assert data.sides.tolist() == [-1.0, -1.0, -1.0, 1.0, 1.0, 1.0]
    held = data.sides[:, None] * data.play_offset  # the lag each row holds
    assert np.all(held >= 0.5 * band - 1e-12) and np.all(held <= band + 1e-12)
    one = measure_twin(model, truth, poses[:3], noise="none", by="goto")  # one side: the profile's
    assert one.sides.tolist() == [-1.0, -1.0, -1.0]
    with pytest.raises(TruthError, match="needs the profile's motion.final_approach"):
        measure_twin(HitchModel(load_profile("thesis-t132")), truth, poses[:1], by="goto", approach="both")
