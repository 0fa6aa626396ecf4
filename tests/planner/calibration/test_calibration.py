"""Geometry calibration: the parametric model, the least-squares fit, identifiability and the pose design."""

from __future__ import annotations

from dataclasses import replace
from functools import cache

import numpy as np
import pytest

from planner.calibration import (
    CalibrationError,
    MeasurementSet,
    ParameterSet,
    ParametricModel,
    build_calibration_problem,
    calibrated_profile_toml,
    candidate_poses,
    identifiable_basis,
    information_log_det,
    plan_poses,
    read_calibration_provenance,
    solve_calibration,
)
from planner.calibration.design import measured_rows
from planner.calibration.parametric import POINT_ROWS, POSE_ROWS
from planner.calibration.profile_out import write_calibrated_profile
from planner.calibration.solve import UNIDENTIFIED_SHARE
from planner.model.kinematics import HitchModel
from planner.profiles.hitch import load_profile, profile_from_dict
from planner.trajectory.final_approach import final_approach_via


@cache
def _profile():
    return load_profile("thesis-t132")


@cache
def _model(rigid: bool = True) -> ParametricModel:
    return ParametricModel(_profile(), rigid_span=rigid)


@cache
def _candidates():
    return candidate_poses(_model(), 120, seed=3)


def _data(model: ParametricModel, readings: np.ndarray, p: np.ndarray, *, points: bool = True) -> MeasurementSet:
    """Exact measurements of the model at parameters ``p`` (independent of the solver: just the forward map)."""
    y, _ = model.batch(readings, p, jacobian=False)
    rows = measured_rows(points=points)
    mask = np.zeros_like(y, dtype=bool)
    mask[:, rows] = True
    return MeasurementSet(readings, np.where(mask, y, np.nan), mask, tuple(str(i) for i in range(len(readings))))


def _visible(model: ParametricModel) -> tuple[np.ndarray, np.ndarray]:
    """24 candidate readings and the parameter directions (scaled) their exact measurements identify."""
    readings = _candidates()[1][:24]
    problem0 = build_calibration_problem(model, _data(model, readings, model.params.nominal))
    _, js = problem0.residuals(np.zeros(len(model.params)))
    assert js is not None
    _, basis, _ = identifiable_basis(js, 1.0)
    return readings, basis


def test_plain_parametric_model_equals_hitch_model_at_nominal():
    model = _model(rigid=False)
    hm = HitchModel(_profile())
    rng = np.random.default_rng(0)
    _, acts = _candidates()
    for q in acts[:10] + rng.normal(0.0, 0.002, (10, 5)):
        st = hm.forward(q)
        ref = np.concatenate([st.pose.as_array(), st.points["L"], st.points["R"], st.points["U"]])
        assert np.max(np.abs(model.predict(q) - ref)) < 1e-12


def test_rigid_model_puts_the_balls_at_the_implement_span():
    model = _model()
    _, acts = _candidates()
    y, _ = model.batch(acts[:5] + np.array([0, 0, 0, 0.003, 0.003]), jacobian=False)
    r = POINT_ROWS
    span = np.linalg.norm(y[:, r["L"] : r["L"] + 3] - y[:, r["R"] : r["R"] + 3], axis=1)
    assert np.allclose(span, model.nominal_model.span, atol=1e-12)


def test_jacobian_matches_central_differences():
    model = _model()
    _, acts = _candidates()
    q = acts[7]
    p0, sc = model.params.nominal, model.params.scale
    _, j = model.batch(q[None, :], p0)
    assert j is not None
    fd = np.zeros_like(j[0])
    for k in range(len(p0)):
        dp = np.zeros_like(p0)
        dp[k] = 1e-4 * sc[k]
        fd[:, k] = (model.predict(q, p0 + dp) - model.predict(q, p0 - dp)) / (2 * dp[k])
    assert np.max(np.abs(fd - j[0])) < 1e-5 * max(1.0, np.max(np.abs(j[0])))


def test_exact_measurements_recover_a_known_perturbation_to_solver_tolerance():
    model = _model()
    readings, basis = _visible(model)
    rng = np.random.default_rng(5)
    u_true = basis @ rng.uniform(-0.8, 0.8, basis.shape[1])  # a tape-sized perturbation the data can see
    p_true = model.params.nominal + model.params.scale * u_true
    res = solve_calibration(build_calibration_problem(model, _data(model, readings, p_true)), snap_ad=False)
    assert res.converged
    assert np.max(np.abs((res.values - p_true) / model.params.scale)) < 1e-7
    assert res.residual_rms_position_m < 1e-10 and res.residual_rms_angle_rad < 1e-10
    assert np.all(res.std < 1e-8 * model.params.scale + 1e-15)
    assert res.residual_rms_nominal_position_m > 1e-4


def test_poor_pose_set_names_the_unidentifiable_combinations():
    model = _model()
    _, acts = _candidates()
    # one pose measured three times: a single actuator state cannot separate most parameters
    readings = np.repeat(acts[:1], 3, axis=0)
    res = solve_calibration(build_calibration_problem(model, _data(model, readings, model.params.nominal)))
    assert res.identified < len(res.names) - 10
    assert len(res.unidentifiable) == len(res.names) - res.identified
    text = " ".join(res.unidentifiable)
    assert "geometry.pivot_height" in text  # no pose measurement sees the pivots' height above ground
    assert all("singular value" in u for u in res.unidentifiable)
    # the unidentified directions stay at nominal
    assert np.allclose(res.values, model.params.nominal, atol=1e-12)


def test_pivot_height_is_never_identifiable_and_stays_nominal():
    model = _model()
    _, acts = _candidates()
    res = solve_calibration(build_calibration_problem(model, _data(model, acts[:20], model.params.nominal)))
    k = model.params.index("geometry.pivot_height")
    assert res.values[k] == model.params.nominal[k]
    assert any("pivot_height" in u for u in res.unidentifiable)
    # its identified share is 0 (its std, ~1e-18, says nothing: the CLI prints "not identified"); the shares
    # are the diagonal of the projector onto the identified subspace: in [0, 1], summing to its dimension
    share = res.identified_share
    assert share[k] < 1e-12 and np.all((share > -1e-12) & (share < 1 + 1e-12))
    assert share.sum() == pytest.approx(res.identified, abs=1e-9)
    assert res.as_dict()["parameters"]["geometry.pivot_height"]["identified_share"] < 1e-12


def test_d_optimal_design_beats_random_poses_in_log_det():
    model = _model()
    d = plan_poses(model, 10, candidates=120, seed=3)
    assert d.poses.shape == (10, 4) and len({tuple(p) for p in d.poses}) == 10
    poses, acts = _candidates()
    sigma = np.where(np.isin(np.arange(15), [3, 4, 5]), 1e-3, 1e-3)
    _, j = model.batch(acts)
    assert j is not None
    rows = measured_rows()
    js = j[:, rows, :] / sigma[rows][None, :, None] * model.params.scale[None, None, :]
    _, basis, _ = identifiable_basis(js.reshape(-1, js.shape[2]), 1.0)
    rng = np.random.default_rng(0)
    random_ld = [information_log_det(js[rng.choice(len(acts), 10, replace=False)], basis) for _ in range(20)]
    _, jd = model.batch(d.actuators)
    assert jd is not None
    design_ld = information_log_det(jd[:, rows, :] / 1e-3 * model.params.scale[None, None, :], basis)
    assert design_ld > max(random_ld)
    assert design_ld == pytest.approx(d.log_det, rel=1e-9)


def test_design_poses_are_reachable_within_the_strokes():
    model = _model()
    d = plan_poses(model, 5, candidates=60, seed=1)
    hm = model.nominal_model
    assert np.all(d.actuators > hm.lower) and np.all(d.actuators < hm.upper)
    for p, q in zip(d.poses, d.actuators, strict=True):
        assert np.allclose(hm.forward(q).pose.controlled(), p, atol=1e-9)


def test_parameters_round_trip_through_a_profile():
    ps = ParameterSet.from_profile(_profile())
    v = ps.nominal.copy()
    v[ps.index("geometry.lift_arm_pivot[1]")] += 0.004
    v[ps.index("ad_offset.lift")] = 2.0 * float(ps.scale[ps.index("ad_offset.lift")]) / 3.0  # 2 counts
    prof = profile_from_dict(ps.profile_dict(v))
    back = ps.values_of(prof)
    assert back[ps.index("geometry.lift_arm_pivot[1]")] == pytest.approx(v[ps.index("geometry.lift_arm_pivot[1]")])
    assert prof.actuators.lift.counts_min == _profile().actuators.lift.counts_min - 2
    assert back[ps.index("ad_offset.lift")] == pytest.approx(v[ps.index("ad_offset.lift")], rel=1e-9)


def test_calibrated_profile_loads_and_carries_provenance(tmp_path):
    model = _model()
    _, acts = _candidates()
    res = solve_calibration(build_calibration_problem(model, _data(model, acts[:12], model.params.nominal)))
    text = calibrated_profile_toml(model.params, res, date="2026-01-01T00:00:00+00:00")
    path = tmp_path / "cal.toml"
    path.write_text(text)
    prof = load_profile(path)
    assert prof.geometry == _profile().geometry
    prov = read_calibration_provenance(path)
    assert prov is not None
    assert prov["date"] == "2026-01-01T00:00:00+00:00" and prov["poses"] == 12
    # a std only where the data see the parameter; those they do not see are named, with no std (it
    # read ~1e-18 before, claiming a certainty nobody has)
    share = dict(zip(res.names, res.identified_share, strict=True))
    assert set(prov["std"]) == {n for n, h in share.items() if h >= UNIDENTIFIED_SHARE}
    assert set(prov["not_identified"]) == {n for n, h in share.items() if h < UNIDENTIFIED_SHARE}
    assert prov["not_identified"] and set(prov["identified_share"]) == set(model.params.names)


def test_copied_rows_are_not_new_poses():
    # one pose copied 20 times: 80 values, yet one pose cannot determine the directions of two; it used to
    # calibrate with sigma-hat 1e-13 and stds of 1e-17 (a spreadsheet slip a commissioning engineer made)
    model = _model()
    _, acts = _candidates()
    one = _data(model, acts[:1], model.params.nominal, points=False)
    rows = one.subset([0] * 20)
    with pytest.raises(CalibrationError, match="20 rows hold 1 distinct pose "):
        solve_calibration(build_calibration_problem(model, rows))
    assert rows.n_distinct_observations == one.n_observations


def test_a_profile_the_planner_cannot_use_is_never_written(tmp_path):
    import dataclasses

    model = _model()
    _, acts = _candidates()
    res = solve_calibration(build_calibration_problem(model, _data(model, acts[:12], model.params.nominal)))
    k = model.params.names.index("geometry.fixed_lift_rod_length")
    broken = dataclasses.replace(res, values=res.values + np.eye(len(res.values))[k] * 0.4)  # 40 cm off
    with pytest.raises(CalibrationError, match="the calibrated profile cannot be used: .* nothing was written"):
        write_calibrated_profile(tmp_path / "bad.toml", model.params, broken)
    assert not (tmp_path / "bad.toml").exists()


def test_bad_solver_options_are_refused():
    model = _model()
    _, acts = _candidates()
    data = _data(model, acts[:3], model.params.nominal)
    with pytest.raises(CalibrationError, match="sigma_position_m"):
        build_calibration_problem(model, data, sigma_position_m=0.0)
    with pytest.raises(CalibrationError, match="min_singular"):
        solve_calibration(build_calibration_problem(model, data), min_singular=-1.0)
    with pytest.raises(CalibrationError, match=r"n \(poses to plan\)"):
        plan_poses(model, 0)


def test_pose_rows_are_the_controlled_pose():
    assert list(POSE_ROWS) == ["x", "z", "roll", "pitch"]


def test_a_design_says_how_many_identifiable_directions_its_poses_separate_and_determine():
    """Three poses (12 measured values) cannot separate the 16 directions the workspace identifies: the
    design's rank says so (the CLI warns); enough poses separate all. ``determined`` is what a
    calibration from exact measurements at the chosen poses identifies (same σ, same threshold)."""
    model = _model()
    few = plan_poses(model, 3, candidates=60, seed=1)
    assert few.rank <= 3 * len(measured_rows()) < few.identifiable
    assert few.determined <= few.rank
    enough = plan_poses(model, 12, candidates=60, seed=1)
    assert enough.rank == enough.identifiable and enough.determined >= few.determined
    for d in (few, enough):
        res = solve_calibration(
            build_calibration_problem(model, _data(model, d.actuators, model.params.nominal, points=False))
        )
        assert res.identified == d.determined, (res.identified, d.determined)


def test_a_calibrated_profile_keeps_home_where_it_was(tmp_path):
    # with the nominal neutral actuators the calibrated geometry moved home (e.g. 16 mrad of roll), and
    # the accuracy test's deflections from there left the workspace (a commissioning engineer's report)
    model = _model()
    _, acts = _candidates()
    ps = model.params
    truth = ps.nominal.copy()
    for name, delta in (("geometry.fixed_lift_rod_length", 0.006), ("geometry.lift_arm_pivot[2]", -0.008)):
        truth[ps.names.index(name)] += delta
    res = solve_calibration(build_calibration_problem(model, _data(model, acts[:20], truth)))
    path = tmp_path / "cal.toml"
    prof = write_calibrated_profile(path, ps, res)
    home = HitchModel(_profile()).neutral_pose.controlled()
    np.testing.assert_allclose(HitchModel(prof).neutral_pose.controlled(), home, atol=1e-8)
    # and the neutral actuators are no longer the nominal ones (the geometry changed)
    assert prof.actuators.tilt.neutral != _profile().actuators.tilt.neutral


def _with_final_approach(offset: dict[str, float], box: dict | None = None) -> ParametricModel:
    data = _profile().model_dump()
    data["motion"]["final_approach"] = offset
    if box is not None:
        data["workspace"]["restricted"][HitchModel(_profile()).category] = box
    return ParametricModel(profile_from_dict(data))


def test_with_a_final_approach_every_planned_pose_is_reached_with_its_whole_approach():
    """A pose at the box's lower face gets a cut-short final approach (the play stays partly taken up; measured
    there, calibrated roll was biased by 1.3 mrad in three of 20 twins through the twin): with the profile's
    final approach, no candidate and no planned pose is one, from wherever the goto starts."""
    offset = {"x": 0.0025, "z": 0.004, "roll": 0.005, "pitch": 0.007}
    d = np.array(list(offset.values()))
    model = _with_final_approach(offset)
    box = model.nominal_model.workspace
    lo = np.array([box[k][0] for k in ("x", "z", "roll", "pitch")])
    hi = np.array([box[k][1] for k in ("x", "z", "roll", "pitch")])
    poses, _ = candidate_poses(model, 60, seed=3)
    design = plan_poses(model, 12, candidates=60, seed=3)
    for pose in np.vstack([poses, design.poses]):
        for start in (hi, lo, pose + d):  # from above, from the lowest corner, from just above
            assert final_approach_via(start, pose, d, lo).short == (), (pose, start)
    assert np.all(poses <= hi) and np.any(np.isclose(poses, lo + d + 1e-4))  # the lower faces moved, no further
    plain = plan_poses(_model(), 12, candidates=60, seed=3).poses  # without: the design's corners are cut short
    assert any(final_approach_via(hi, p, d, lo).short for p in plain)


def test_a_final_approach_wider_than_the_box_is_refused_naming_the_dof():
    box = {"x": (-0.06, 0.06), "z": (-0.2, 0.3), "roll": (-0.004, 0.004), "pitch": (-0.1, 0.05)}
    model = _with_final_approach({"x": 0.0025, "z": 0.004, "roll": 0.0079, "pitch": 0.007}, box)
    with pytest.raises(CalibrationError, match=r"narrower in roll than the profile's motion.final_approach"):
        candidate_poses(model, 10)


# ---------------------------------------------------------------- the lag of the pin play (two-sided measurements)
OFFSET = {"x": 0.0025, "z": 0.004, "roll": 0.005, "pitch": 0.007}


@cache
def _lag_model() -> ParametricModel:
    prof = _with_final_approach(OFFSET).profile
    return ParametricModel(prof, params=ParameterSet.from_profile(prof, include_lag=True))


def _sided(model: ParametricModel, readings: np.ndarray, p: np.ndarray, sides: np.ndarray) -> MeasurementSet:
    """Exact pose measurements at ``sides``: the forward map shifted by side · lag, written out here (the pose
    rows x, z, roll, pitch), not through the model's own lag term."""
    y, _ = model.batch(readings, p, jacobian=False)  # sides 0: the mechanism alone
    lag = p[model.params.lag_index]
    rows = [POSE_ROWS[k] for k in ("x", "z", "roll", "pitch")]
    y[:, rows] += sides[:, None] * lag[None, :]
    mask = np.zeros_like(y, dtype=bool)
    mask[:, rows] = True
    labels = tuple(str(i) for i in range(len(readings)))
    return MeasurementSet(readings, np.where(mask, y, np.nan), mask, labels, sides)


def test_the_lag_shifts_the_pose_by_the_side_and_its_jacobian_matches_central_differences():
    model = _lag_model()
    ps = model.params
    assert ps.names[-4:] == ("lag.x", "lag.z", "lag.roll", "lag.pitch")
    _, acts = _candidates()
    q = acts[7]
    p0 = ps.nominal.copy()
    p0[ps.lag_index] = [0.0008, 0.0006, 0.002, 0.0025]
    rows = [POSE_ROWS[k] for k in ("x", "z", "roll", "pitch")]
    for side in (-1.0, 0.0, 1.0):
        y = model.predict(q, p0, side=side)
        assert y[rows] - model.predict(q, p0)[rows] == pytest.approx(side * p0[ps.lag_index], abs=1e-15)
        _, j = model.batch(q[None, :], p0, sides=np.array([side]))
        assert j is not None
        fd = np.zeros_like(j[0])
        for k in range(len(p0)):
            dp = np.zeros_like(p0)
            dp[k] = 1e-4 * ps.scale[k]
            fd[:, k] = (model.predict(q, p0 + dp, side) - model.predict(q, p0 - dp, side)) / (2 * dp[k])
        assert np.max(np.abs(fd - j[0])) < 1e-5 * max(1.0, np.max(np.abs(j[0])))


def test_two_sided_exact_measurements_recover_the_lag_and_a_known_perturbation_to_solver_tolerance():
    model = _lag_model()
    ps = model.params
    _, acts = _candidates()
    readings = np.vstack([acts[:24], acts[:24]])
    sides = np.repeat([-1.0, 1.0], 24)
    problem0 = build_calibration_problem(model, _sided(model, readings, ps.nominal, sides))
    _, js = problem0.residuals(np.zeros(len(ps)))
    assert js is not None
    _, basis, _ = identifiable_basis(js, 1.0)
    rng = np.random.default_rng(5)
    u_true = basis @ rng.uniform(-0.8, 0.8, basis.shape[1])
    p_true = ps.nominal + ps.scale * u_true
    p_true[ps.lag_index] = [0.0008, 0.0006, 0.002, 0.0025]  # the lag is seen whole from two sides
    res = solve_calibration(build_calibration_problem(model, _sided(model, readings, p_true, sides)), snap_ad=False)
    assert res.converged
    assert res.identified_share[ps.lag_index] == pytest.approx(1.0, abs=1e-9)
    assert res.values[ps.lag_index] == pytest.approx(p_true[ps.lag_index], abs=1e-10)
    assert np.max(np.abs((res.values - p_true) / ps.scale)) < 1e-7


def test_from_one_side_the_lag_is_not_identified_and_is_named():
    model = _lag_model()
    ps = model.params
    _, acts = _candidates()
    readings = acts[:24]
    res = solve_calibration(build_calibration_problem(model, _sided(model, readings, ps.nominal, -np.ones(24))))
    assert np.all(res.identified_share[ps.lag_index] < 0.5)  # mostly a constant offset the geometry can also make
    assert any("lag." in u for u in res.unidentifiable)
    # without a side the lag has no effect at all: a zero column, never identified
    res0 = solve_calibration(build_calibration_problem(model, _sided(model, readings, ps.nominal, np.zeros(24))))
    assert np.all(res0.identified_share[ps.lag_index] < UNIDENTIFIED_SHARE)


def test_the_lag_needs_a_final_approach_and_round_trips_through_the_profile():
    with pytest.raises(CalibrationError, match="motion.final_approach"):
        ParameterSet.from_profile(_profile(), include_lag=True)
    ps = _lag_model().params
    v = ps.nominal.copy()
    v[ps.lag_index] = [0.0008, -0.0001, 0.002, 0.0025]
    prof = profile_from_dict(ps.profile_dict(v))
    assert prof.motion.final_approach.lag.vector() == pytest.approx((0.0008, -0.0001, 0.002, 0.0025))
    assert ps.values_of(prof)[ps.lag_index] == pytest.approx(v[ps.lag_index])
    # a calibration of the calibrated profile starts from its lag
    again = ParameterSet.from_profile(prof, include_lag=True)
    assert again.nominal[again.lag_index] == pytest.approx(v[ps.lag_index])


def test_two_sided_candidates_keep_the_approach_s_room_at_both_faces():
    d = np.array(list(OFFSET.values()))
    model = _with_final_approach(OFFSET)
    box = model.nominal_model.workspace
    lo = np.array([box[k][0] for k in ("x", "z", "roll", "pitch")])
    hi = np.array([box[k][1] for k in ("x", "z", "roll", "pitch")])
    poses, _ = candidate_poses(model, 60, seed=3, two_sided=True)
    for pose in poses:
        for start in (hi, lo):
            assert final_approach_via(start, pose, d, lo, hi).short == ()
            assert final_approach_via(start, pose, -d, lo, hi).short == ()
    one_sided, _ = candidate_poses(model, 60, seed=3)
    assert any(final_approach_via(lo, p, -d, lo, hi).short for p in one_sided)  # from above: cut at the top
    with pytest.raises(CalibrationError, match="final_approach"):
        candidate_poses(_model(), 10, two_sided=True)


def test_the_lag_is_a_parameter_only_in_the_dof_the_approach_moves():
    prof = _with_final_approach({**OFFSET, "x": 0.0}).profile
    ps = ParameterSet.from_profile(prof, include_lag=True)
    assert [n for n in ps.names if n.startswith("lag.")] == ["lag.z", "lag.roll", "lag.pitch"]
    assert ps.lag_dofs == (1, 2, 3)
    model = ParametricModel(prof, params=ps)
    _, acts = _candidates()
    p = ps.nominal.copy()
    p[ps.lag_index] = [0.0006, 0.002, 0.0025]
    shift = model.predict(acts[3], p, side=-1.0) - model.predict(acts[3], p)
    rows = [POSE_ROWS[k] for k in ("x", "z", "roll", "pitch")]
    assert shift[rows] == pytest.approx([0.0, -0.0006, -0.002, -0.0025], abs=1e-15)


def test_the_same_readings_from_the_other_side_are_new_values_not_a_copied_row():
    """A static pair (or a pair under the count approach) has the same counts from both sides: the pair holds the
    lag, and was refused as "a copied row is not a new pose" (a reviewer's report)."""
    model = _lag_model()
    _, acts = _candidates()
    readings = np.repeat(acts[:4], 2, axis=0)
    sides = np.tile([-1.0, 1.0], 4)
    data = _sided(model, readings, model.params.nominal, sides)
    assert data.n_distinct_observations == 8 * 4 and data.n_poses == 4
    assert data.two_sided and not data.subset([0, 2, 4]).two_sided


def test_poses_measured_from_both_sides_count_once_whatever_their_labels_say():
    """``n_poses`` (the provenance's "poses"): 20 poses from both sides are 20, not 40 (readings differ by the
    lag); labels are not evidence (empty or an operator's name on every row made them one pose)."""
    model = _lag_model()
    _, acts = _candidates()
    below, above = acts[:6], acts[:6] + 1e-3  # the other side's readings differ by the lag
    readings = np.vstack([below, above])
    sides = np.repeat([-1.0, 1.0], 6)
    data = _sided(model, readings, model.params.nominal, sides)
    assert data.n_poses == 6
    for labels in ([""] * 12, ["alice"] * 12, [f"p{k}" for k in range(12)]):
        assert replace(data, labels=tuple(labels)).n_poses == 6
    assert data.subset(range(6)).n_poses == 6 and data.subset([0, 1, 8]).n_poses == 2  # p3 from above only
    unsided = replace(data, sides=np.zeros(12))
    assert unsided.n_poses == 12  # no side known: distinct readings
    repeat = replace(data, readings=np.vstack([below, below]), sides=np.full(12, -1.0))
    assert repeat.n_poses == 6  # the same readings again from the same side: a repeat


def test_the_approach_room_a_pose_needs_is_the_offset_less_the_lag_from_either_side():
    """With a lag the mechanism is aimed beyond the goal and its via with it: a pose needs the offset less the lag
    before the face (a reviewer's note: it was warned about by the lag too early)."""
    from planner.calibration.design import approach_shortfalls

    lag = {"x": 0.001, "z": 0.0015, "roll": 0.002, "pitch": 0.003}
    model = _with_final_approach({**OFFSET, "lag": lag})
    box = model.nominal_model.workspace
    lo = np.array([box[k][0] for k in ("x", "z", "roll", "pitch")])
    hi = np.array([box[k][1] for k in ("x", "z", "roll", "pitch")])
    need = np.array([OFFSET[k] - lag[k] for k in ("x", "z", "roll", "pitch")])
    mid = (lo + hi) / 2
    for k, name in enumerate(("x", "z", "roll", "pitch")):
        for side, face, sign in (("below", lo, 1.0), ("above", hi, -1.0)):
            p = mid.copy()
            p[k] = face[k] + sign * (need[k] + 1e-6)  # just enough room
            assert approach_shortfalls(model, p[None, :], (side,)) == ()
            p[k] = face[k] + sign * (need[k] - 1e-4)
            (short,) = approach_shortfalls(model, p[None, :], (side,))
            assert (short.dof, short.side) == (name, side)
            assert short.offset == pytest.approx(need[k]) and short.room == pytest.approx(need[k] - 1e-4)


def test_a_fit_that_leaves_the_schema_blames_the_measurements_not_a_unit_in_the_profile():
    """A commissioning trial with the L and R points swapped: the fit ended at lower_link_pivot_span = 3.23 m and
    the error said "did you mean mm? 3.22544 mm = 0.00322544 m", sending the engineer to write a fitted value in
    mm. The value was fitted, not typed: the message names the measurements' likely slips instead."""
    from planner.calibration.parameters import ParameterSet

    ps = ParameterSet.from_profile(load_profile("thesis-t132"), include_ad=False)
    values = ps.nominal.copy()
    values[ps.index("geometry.lower_link_pivot_span")] = 3.22544
    with pytest.raises(CalibrationError) as exc:
        ps.profile_dict(values)
    text = str(exc.value)
    assert "geometry.lower_link_pivot_span" in text and "did you mean" not in text, text
    assert "the L and R points swapped" in text and "the measurements do not fit the model" in text, text


def test_the_ad_count_jacobian_matches_central_differences_of_whole_counts():
    ps = _model().params
    prof = _profile()
    rng = np.random.default_rng(8)
    data = prof.model_dump()
    for n in ("lift", "tilt", "top", "left", "right"):  # a map some counts off the nominal one
        a = data["actuators"][n]
        a["counts_min"] += int(rng.integers(-4, 5))
        a["counts_max"] += int(rng.integers(-4, 5))
    base = profile_from_dict(data)
    v = ps.values_of(base)
    jac = ps.ad_count_jacobian(v)
    fd = np.zeros_like(jac)
    for k, n in enumerate(("lift", "tilt", "top", "left", "right")):
        for c, key in enumerate(("counts_min", "counts_max")):
            moved = []
            for step in (1, -1):
                d = base.model_dump()
                d["actuators"][n][key] += step
                moved.append(ps.values_of(profile_from_dict(d)))
            fd[:, 2 * k + c] = (moved[0] - moved[1]) / 2.0
    ad = np.array([name.startswith("ad_") for name in ps.names])
    assert np.all(jac[~ad] == 0.0)
    # central differences over one whole count: exact for the offset's linear terms, O(1e-6) relative for 1/span
    assert np.max(np.abs(fd - jac) / ps.scale[:, None]) < 1e-5
    assert np.max(np.abs(jac[ad]) / ps.scale[ad, None]) > 0.1  # not a zero map


def test_the_written_profile_s_std_holds_the_rounding_of_its_ad_map_to_whole_counts():
    """With exact measurements the continuous fit has σ ≈ 0, but the profile stores its AD map in whole counts:
    the values written are off the truth by the rounding. Their std must say so (it was the continuous fit's,
    ~1e-9 of a tape size, so the written values lay millions of σ from the truth)."""
    model = _model()
    readings, basis = _visible(model)
    rng = np.random.default_rng(21)
    z = []
    for _ in range(6):
        u_true = basis @ rng.uniform(-0.8, 0.8, basis.shape[1])
        p_true = model.params.nominal + model.params.scale * u_true
        res = solve_calibration(build_calibration_problem(model, _data(model, readings, p_true)))
        err = res.values - p_true
        moved = np.abs(err) > 1e-9 * model.params.scale
        assert moved.sum() >= 5  # the rounding moved the AD map (and the geometry's refit) off the truth
        z.append(err[moved] / res.std[moved])
    zs = np.concatenate(z)
    assert np.max(np.abs(zs)) < 4.0
    assert 0.4 < float(np.sqrt(np.mean(zs**2))) < 1.6  # a rounding spread the std describes
