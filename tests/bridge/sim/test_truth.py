"""The twin's own true machine: truth = nominal reproduces today's twin bit for bit; an AD offset shifts
the reported counts by exactly that; a geometry error changes the true pose and not the counts; pin
play is a dead band; the tape perturbation's sizes; the instrument's noise; bad inputs."""

import math

import numpy as np
import pytest

from bridge.sim.rig import SimError, SimRig, SimSettings
from bridge.sim.truth import (
    COORDINATE_FIELDS,
    LENGTH_FIELDS,
    Instrument,
    InstrumentNoise,
    MachineTruth,
    PinPlay,
    TrueMachine,
    TruthError,
    load_machine_truth,
    perturb_profile,
    truth_toml,
)
from planner.errors import HitchInputError
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES
from planner.profiles.hitch import load_profile, profile_from_dict
from planner.trajectory import TrajectoryPlanner

LIFT, TILT = ACTUATOR_NAMES.index("lift"), ACTUATOR_NAMES.index("tilt")


def variant(profile, edit) -> MachineTruth:
    data = profile.model_dump()
    edit(data)
    return MachineTruth(profile_from_dict(data))


def drive(model, truth, *, seconds=1.0, noise_counts=0.0):
    """Warm up, then stream the nominal IK of a 50 mm lowering at 50 Hz; record every tick."""
    goal = TrajectoryPlanner(model).inverse.solve(model.neutral_pose.controlled() + np.array([0.0, -0.05, 0, 0]))[0]
    rec = {"counts": [], "pistons": [], "link": [], "true": []}
    with SimRig(model, SimSettings(noise_counts=noise_counts, seed=4), truth=truth) as rig:
        rig.start()
        rig.run_until(0.5)
        t_end = rig.now_s + seconds
        while rig.now_s < t_end - 1e-9:
            if round(rig.now_s * 1000) % 20 == 0:
                rig.link.send_reference(goal, rig.next_tick_s)
            rig.tick()
            st = rig.link.latest_state()
            rec["counts"].append(rig.ecu.measurement_counts().copy())
            rec["pistons"].append(rig.ecu.piston_counts().copy())
            rec["link"].append(st.pose.controlled() if st is not None else np.full(4, np.nan))
        rec["true"].append(rig.true_pose().controlled())
        rec["params"] = rig.ecu.params
    return {k: (np.array(v) if k != "params" else v) for k, v in rec.items()}


# -- truth = nominal -------------------------------------------------------------------------------
def test_a_truth_equal_to_nominal_reproduces_todays_twin_bit_for_bit(model, tmp_path):
    # the truth goes through the file format and the loader: what a user would give with --sim-truth
    path = tmp_path / "same.toml"
    path.write_text(truth_toml(model.profile.model_dump()), encoding="utf-8")
    truth = load_machine_truth(path)
    assert truth.profile == model.profile and not truth.play.any
    today = drive(model, None, noise_counts=0.7)
    same = drive(model, truth, noise_counts=0.7)
    for k in ("counts", "pistons", "link", "true"):
        assert np.array_equal(today[k], same[k], equal_nan=True), k
    # without the rigid-implement correction the true pose is today's "simulation truth", bit for bit:
    # nominal FK of the pistons through the ECU's calibration
    q = [p.counts_to_si(c) for p, c in zip(today["params"], today["pistons"][-1], strict=True)]
    plain = TrueMachine(truth, model.category, model=model, rigid_span=False)
    assert np.array_equal(
        plain.observe(today["pistons"][-1]).controlled(), model.forward(np.array(q)).pose.controlled()
    )
    # with it (the default), a fraction of a millimetre from that: the pistons sit within a count of the IK
    gap = today["true"][-1] - model.forward(np.array(q)).pose.controlled()
    assert np.all(np.abs(gap) < 3e-4)
    assert np.ptp(today["counts"][:, LIFT]) > 5  # it really moved


# -- AD offsets ------------------------------------------------------------------------------------
def offset_truth(profile, offsets):
    def edit(d):
        for n, o in offsets.items():
            d["actuators"][n]["counts_min"] += o
            d["actuators"][n]["counts_max"] += o

    return variant(profile, edit)


def held(model, truth, q):
    with SimRig(model, truth=truth, initial_actuators=q) as rig:
        rig.start()
        rig.run_until(0.5)
        return rig.ecu.measurement_counts(), rig.link.latest_state(), rig.true_pose().controlled()


def test_a_perturbed_ad_offset_shifts_the_reported_counts_by_exactly_that(model):
    offsets = {"lift": 3, "tilt": -2, "right": 1}
    truth = offset_truth(model.profile, offsets)
    q = TrajectoryPlanner(model).inverse.solve(model.neutral_pose.controlled() + np.array([0.01, 0.05, 0.02, 0]))[0]
    c0, s0, true0 = held(model, None, q)
    c1, s1, true1 = held(model, truth, q)
    expected = np.array([offsets.get(n, 0) for n in ACTUATOR_NAMES])
    assert np.array_equal(c1 - c0, expected)
    # the pistons sit at the same true positions: the true pose is unchanged
    assert np.allclose(true1, true0, atol=1e-9)
    # the planner (nominal map) believes the pistons moved by the offset: its pose shifts by ≈ J Δq
    res = SensorScaling(model.profile).resolution
    dq = expected * res
    _, jac = model.features(s0.actuators.as_array())
    predicted = jac[[0, 2, 3, 4]] @ dq
    shift = s1.pose.controlled() - s0.pose.controlled()
    assert np.all(np.abs(shift - predicted) <= 0.05 * np.abs(predicted) + 1e-5)
    assert abs(shift[1]) > 0.005  # 3 lift counts ≈ 11.6 mrad of lift angle: a centimetre in z


# -- geometry --------------------------------------------------------------------------------------
def test_a_perturbed_geometry_changes_the_true_pose_and_not_the_counts(model):
    delta = 0.005  # the fixed (left) lift rod 5 mm long
    truth = variant(model.profile, lambda d: d["geometry"].update(fixed_lift_rod_length=0.630 + delta))
    nominal = drive(model, None)
    perturbed = drive(model, truth)
    for k in ("counts", "pistons", "link"):  # the ECU and the planner see exactly the same
        assert np.array_equal(nominal[k], perturbed[k], equal_nan=True), k
    # independent truth: the left rod is the mirror image of the right lift rod (the tilt cylinder),
    # so lengthening it by δ moves the pose like the tilt cylinder's column of J, mirrored (x, roll flip)
    _, jac = model.features(model.neutral)
    col = jac[[0, 2, 3, 4], TILT] * delta
    mirrored = np.array([-col[0], col[1], -col[2], col[3]])
    with SimRig(model, truth=truth) as rig, SimRig(model) as rig0:
        d = rig.true_pose().controlled() - rig0.true_pose().controlled()
    assert np.all(np.abs(d - mirrored) <= 0.08 * np.abs(mirrored) + 2e-4)
    assert abs(d[2]) > 0.015  # ≈ 18.6 mrad of roll from 5 mm of rod length
    # after the drive, the planner's measured pose differs from the true pose by that, plus the
    # planner's AD quantisation (the same in both rigs)
    quant = perturbed["link"][-1] - nominal["true"][-1]
    err = perturbed["link"][-1] - perturbed["true"][-1]
    assert np.allclose(err - quant, nominal["true"][-1] - perturbed["true"][-1])
    assert np.all(np.abs((err - quant) + mirrored) <= 0.1 * np.abs(mirrored) + 5e-4)


# -- play ------------------------------------------------------------------------------------------
def test_pin_play_is_a_dead_band_per_dof(model):
    play = PinPlay(lower_link_m=0.0008, top_link_m=0.0006)
    tm = TrueMachine(MachineTruth(model.profile, play), model.category, model=model, rigid_span=False)
    band = np.array([0.0008, 0.0008, 2 * 0.0008 / model.span, 0.0014 / model.mast_height])
    assert np.allclose(tm.band, band)
    sc = SensorScaling(model.profile)
    base = sc.counts_min + (model.neutral - sc.si_min) / sc.resolution
    mech = lambda c: model.pose(sc.si_min + (c - sc.counts_min) * sc.resolution).controlled()  # noqa: E731
    assert np.allclose(tm.observe(base).controlled(), mech(base))  # starts centred
    up = base + np.array([4.0, 0, 0, 0, 0])  # lift: z rises by several mm
    for k in np.linspace(0, 1, 11):
        tm.observe(base + k * (up - base))
    lag = tm.pose.controlled() - mech(up)
    assert lag[1] == pytest.approx(-band[1], abs=1e-12)  # trails by the band, below
    # a small reversal inside the dead band leaves the implement where it is
    back = up - np.array([0.1, 0, 0, 0, 0])
    z_before = tm.pose.z
    assert abs(mech(back)[1] - mech(up)[1]) < band[1]
    tm.observe(back)
    assert tm.pose.z == z_before
    # marked points move with the implement (rigidly, by the lag)
    pts = tm.points(("L", "R"))
    state = model.forward(sc.si_min + (back - sc.counts_min) * sc.resolution)
    moved = np.mean([pts["L"][2] - state.points["L"][2], pts["R"][2] - state.points["R"][2]])
    assert moved == pytest.approx(tm.pose.z - state.pose.z, abs=1e-9)


def test_a_rig_with_play_tracks_the_dead_band_every_tick(model):
    truth = MachineTruth(model.profile, PinPlay(0.001, 0.0))
    goal = TrajectoryPlanner(model).inverse.solve(model.neutral_pose.controlled() + np.array([0.0, 0.04, 0, 0]))[0]
    lags, mech_z = [], []
    with SimRig(model, truth=truth) as rig:
        rig.start()
        rig.run_until(0.5)
        while rig.now_s < 2.0:
            rig.link.send_reference(goal, rig.next_tick_s)
            rig.tick()
            mech = model.pose(rig.true_machine.mechanism_actuators(rig.ecu.piston_counts())).controlled()
            lags.append(rig.true_machine.pose.controlled() - mech)
            mech_z.append(mech[1])
    lag_z, rise = np.array(lags)[:, 1], np.diff(mech_z, prepend=mech_z[0])
    assert np.all(np.abs(lag_z) <= 0.001 + 1e-12)  # never outside the dead band
    first_rise = (rise > 1e-5) & (np.array(mech_z) - mech_z[0] > 0.002) & (np.arange(len(rise)) < np.argmax(mech_z))
    assert first_rise.sum() > 20
    assert np.allclose(lag_z[first_rise], -0.001)  # while lifting, the implement hangs 1 mm low
    assert np.allclose(lag_z[:5], 0.0, atol=2e-4)  # it starts centred, the lag builds up over the play
    assert np.max(mech_z) - mech_z[0] > 0.03


# -- perturbation ----------------------------------------------------------------------------------
def test_perturb_sizes_are_within_the_stated_bounds_and_seeded(tmp_path):
    nom = load_profile("thesis-t132")
    geo = nom.geometry.model_dump()
    worst = {"coord": 0.0, "length": 0.0, "offset": 0, "gain": 0.0, "play": 0.0}
    for seed in range(12):
        data, play = perturb_profile(nom, seed)
        for k in COORDINATE_FIELDS:
            e = np.abs(np.subtract(data["geometry"][k], geo[k]))
            worst["coord"] = max(worst["coord"], float(np.max(e)))
        for k in LENGTH_FIELDS:
            worst["length"] = max(worst["length"], abs(data["geometry"][k] - geo[k]))
        for n in ACTUATOR_NAMES:
            a, t = nom.actuator(n), data["actuators"][n]
            off = t["counts_min"] - a.counts_min
            assert isinstance(t["counts_min"], int) and isinstance(t["counts_max"], int)
            worst["offset"] = max(worst["offset"], abs(off))
            span = a.counts_max - a.counts_min
            worst["gain"] = max(worst["gain"], abs((t["counts_max"] - t["counts_min"]) / span - 1))
            assert (t["min"], t["max"]) == (a.min, a.max)  # the end stops stay
        worst["play"] = max(worst["play"], play.lower_link_m, play.top_link_m)
        assert min(play.lower_link_m, play.top_link_m) >= 0
        for section in ("implement", "limits", "workspace", "motion", "stability"):
            assert data[section] == nom.model_dump()[section]
        path = tmp_path / f"t{seed}.toml"
        path.write_text(truth_toml(data, play), encoding="utf-8")
        assert load_profile(path).model_dump() == profile_from_dict(data).model_dump()  # the normal loader
        assert load_machine_truth(path).play == play
    assert 0.005 < worst["coord"] <= 0.010
    assert 0.0025 < worst["length"] <= 0.005
    assert worst["offset"] == 3
    assert 0.005 < worst["gain"] <= 0.02
    assert 0.0005 < worst["play"] <= 0.001
    a, b = perturb_profile(nom, 7), perturb_profile(nom, 7)
    assert truth_toml(*a) == truth_toml(*b)
    assert truth_toml(*a) != truth_toml(*perturb_profile(nom, 8))


# -- instrument ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def machine(model):
    tm = TrueMachine(MachineTruth(model.profile), model.category, model=model)
    sc = SensorScaling(model.profile)
    tm.observe(sc.counts_min + (model.neutral - sc.si_min) / sc.resolution)
    return tm


def errors(machine, noise, n=3000, seed=1):
    inst = Instrument(noise, seed=seed)
    true = machine.pose.controlled()
    pts = machine.points(("L", "U"))
    pose_err, pt_err = [], []
    for _ in range(n):
        m = inst.measure(machine, ("L", "U"))
        pose_err.append(np.array([m.pose[k] for k in ("x", "z", "roll", "pitch")]) - true)
        pt_err.append(np.concatenate([np.subtract(m.points[k], pts[k]) for k in ("L", "U")]))
    return np.array(pose_err), np.array(pt_err)


def test_station_noise_is_gaussian_1mm_1mrad(machine):
    pose, pts = errors(machine, "station")
    assert np.allclose(pose.std(axis=0), 0.001, rtol=0.06)
    assert np.allclose(pts.std(axis=0), 0.001, rtol=0.06)
    assert np.all(np.abs(pose.mean(axis=0)) < 0.0001)
    assert np.max(np.abs(pts)) > 0.003  # Gaussian tails, not a bounded band


def test_tape_noise_is_uniform_10mm(machine):
    pose, pts = errors(machine, "tape")
    assert np.max(np.abs(pts)) <= 0.010 and np.max(np.abs(pose[:, :2])) <= 0.010
    assert np.max(np.abs(pose[:, 2:])) <= 0.020
    assert np.allclose(pts.std(axis=0), 0.010 / math.sqrt(3), rtol=0.06)
    assert np.max(np.abs(pts)) > 0.0098


def test_no_noise_is_exact_and_readings_are_seeded(machine):
    pose, pts = errors(machine, "none", n=3)
    assert not pose.any() and not pts.any()
    a, _ = errors(machine, "station", n=5, seed=3)
    b, _ = errors(machine, "station", n=5, seed=3)
    c, _ = errors(machine, "station", n=5, seed=4)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


# -- bad inputs ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("make", "words"),
    [
        (lambda: PinPlay(lower_link_m=-0.001), ("play.lower_link_m", "[0, 0.01]")),
        (lambda: PinPlay(top_link_m=math.nan), ("play.top_link_m", "[0, 0.01]")),
        (lambda: perturb_profile("thesis-t132", -1), ("seed", "[0, 2^63)")),
        (lambda: perturb_profile("thesis-t132", 1, tape=False), ("tape",)),
        (lambda: Instrument("laser"), ("noise", "tape, station, none")),
        (lambda: Instrument("station", seed=-2), ("seed", "non-negative")),
        (lambda: InstrumentNoise("uniform", -1.0, 0.0), ("position_m", "[0, 1]")),
        (lambda: MachineTruth("thesis-t132"), ("truth profile",)),  # type: ignore[arg-type]
        (lambda: MachineTruth.nominal().si_from_counts([1, 2]), ("counts", "5")),
    ],
)
def test_bad_inputs_name_the_field_and_range(make, words):
    with pytest.raises(HitchInputError) as e:
        make()
    assert isinstance(e.value, TruthError)
    for w in words:
        assert w in str(e.value)


def test_bad_points_and_unobserved_machine(model):
    tm = TrueMachine(MachineTruth(model.profile), model=model)
    with pytest.raises(TruthError, match="observed"):
        tm.pose  # noqa: B018
    with pytest.raises(TruthError, match="unknown point"):
        tm.points(("Z9",))
    with pytest.raises(SimError, match="truth must be a MachineTruth"):
        SimRig(model, truth="thesis-t132")  # type: ignore[arg-type]


def test_a_bad_play_line_names_the_field(tmp_path, model):
    path = tmp_path / "bad.toml"
    text = truth_toml(model.profile.model_dump(), PinPlay(0.0005, 0.0))
    path.write_text(text.replace("lower_link_m = 0.0005", "lower_link_m = 0.5"), encoding="utf-8")
    with pytest.raises(TruthError, match=r"truth .*bad.toml: play.lower_link_m must be a number in \[0, 0.01\]"):
        load_machine_truth(path)
    path.write_text(text.replace("lower_link_m", "balls_m"), encoding="utf-8")
    with pytest.raises(TruthError, match="lower_link_m, top_link_m"):
        load_machine_truth(path)
    # an attacker's report: a misspelt directive ran as a truth without play; of two play lines the first won
    path.write_text(text.replace("#! sim-truth play", "#! sim-truth flay"), encoding="utf-8")
    with pytest.raises(TruthError, match=r"bad.toml line \d+: unknown directive #! sim-truth 'flay'"):
        load_machine_truth(path)
    # a commissioning engineer's report: "#! sim_truth play" (underscore) ran as a truth without play, silently
    path.write_text(text.replace("#! sim-truth play", "#! sim_truth play"), encoding="utf-8")
    with pytest.raises(TruthError, match=r"bad.toml line \d+: unknown directive '#! sim_truth' \(known: #! sim-truth"):
        load_machine_truth(path)
    path.write_text(text.replace("lower_link_m", "lower_lnk_m"), encoding="utf-8")
    with pytest.raises(TruthError, match=r"\(unknown: lower_lnk_m\)"):  # the wrong key, named
        load_machine_truth(path)
    line = next(ln for ln in text.splitlines() if ln.startswith("#! sim-truth play"))
    path.write_text(text.replace(line, line + "\n" + line), encoding="utf-8")
    with pytest.raises(TruthError, match=r"bad.toml: 2 play lines"):
        load_machine_truth(path)


def test_a_truth_whose_model_differs_is_built_separately(model):
    truth = perturb_profile(model.profile, 2)
    tm = TrueMachine(MachineTruth(profile_from_dict(truth[0]), truth[1]), model.category)
    assert isinstance(tm.model, HitchModel) and tm.model is not model
    assert tm.model.profile.geometry != model.profile.geometry


def test_the_rigid_implement_keeps_its_span_when_the_limiter_geometry_is_off(model):
    # 10 mm on the sway limiter's tractor point along y moves plain FK's ball span by about 13 cm
    def edit(d):
        x, y, z = d["geometry"]["limiter_tractor_point"]
        d["geometry"]["limiter_tractor_point"] = (x, y + 0.010, z)

    truth = variant(model.profile, edit)
    counts = truth.counts_from_si(model.neutral)
    plain = TrueMachine(truth, model.category, rigid_span=False)
    rigid = TrueMachine(truth, model.category, model=plain.model)
    plain.observe(counts)
    rigid.observe(counts)
    span = lambda tm: float(np.linalg.norm(tm.points(("L",))["L"] - tm.points(("R",))["R"]))  # noqa: E731
    assert abs(span(plain) - model.span) > 0.05
    assert span(rigid) == pytest.approx(model.span, abs=1e-8)
    assert plain.limiter_strain_m == 0.0 and 0.001 < abs(rigid.limiter_strain_m) < 0.02
    # the lateral position the limiters' difference sets is kept (the mechanism is symmetric here)
    assert rigid.pose.x == pytest.approx(0.0, abs=1e-6)


# -- every hitch sim command takes the truth ------------------------------------------------------
def test_run_move_on_an_ad_offset_truth_ends_where_the_offset_puts_the_true_pistons(model):
    from bridge.sim.move import run_move

    offsets = {"lift": 3}
    truth = offset_truth(model.profile, offsets)
    nominal = run_move(model, {"z": 0.1})
    same = run_move(model, {"z": 0.1}, truth=MachineTruth.nominal(model.profile))
    off = run_move(model, {"z": 0.1}, truth=truth)
    assert np.array_equal(nominal.truth, same.truth) and np.array_equal(nominal.measured, same.measured)
    # the ECU drives the pistons until the TRUE reading is the commanded count: the true lift sits 3 counts
    # (of the nominal resolution) below what the planner believes; its pose is off by about -J dq
    res = SensorScaling(model.profile).resolution
    dq = -np.array([offsets.get(n, 0) for n in ACTUATOR_NAMES]) * res
    _, jac = model.features(TrajectoryPlanner(model).inverse.solve(off.measured[-1])[0])
    predicted = jac[[0, 2, 3, 4]] @ dq
    gap = off.truth[-1] - off.measured[-1]
    assert abs(predicted[1]) > 0.008  # about a centimetre of z
    assert abs(gap[1] - predicted[1]) < 0.4 * abs(predicted[1])  # within a count of piston play in its band
    # without the truth the measured and true poses agree to a count
    assert abs(nominal.truth[-1][1] - nominal.measured[-1][1]) < 0.4 * abs(predicted[1])
