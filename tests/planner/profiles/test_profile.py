"""Profile loading: thesis numbers in SI, and validation errors field by field."""

import copy
import math
import tomllib
from importlib import resources

import pytest

from planner.profiles.hitch import ProfileError, available_profiles, load_profile, profile_from_dict


@pytest.fixture(scope="module")
def raw() -> dict:
    return tomllib.loads((resources.files("planner") / "profiles" / "thesis-t132.toml").read_text())


def test_default_profile_carries_the_thesis_numbers_in_si():
    p = load_profile()
    g = p.geometry
    # table 3-5 (mm in the thesis)
    assert (g.lower_link_pivot_span, g.lower_link_length) == (0.600, 0.960)
    assert g.top_link_tractor_point == (0.0, 0.230, 0.520)
    assert (g.lift_rod_attachment, g.limiter_bracket_position, g.fixed_lift_rod_length) == (0.300, 0.540, 0.630)
    assert g.lift_arm_pivot == (0.0, -0.150, 0.580) and g.lift_arm_length == 0.300
    assert g.limiter_bracket_offset == 0.290
    # table 3-6 + the 40 mm ball-centre correction, applied in Profile.span only
    assert p.implement.categories["2"].span == 0.825
    assert p.span("2") == pytest.approx(0.865)
    assert p.span("2N") == pytest.approx(0.683 + 0.040) and p.category("2N").mast_height == 0.610
    assert list(p.implement.categories) == ["1N", "1", "2N", "2", "3N", "3", "4N", "4"]
    # tables 3-1 .. 3-4
    a = p.actuators
    assert (a.tilt.min, a.tilt.max, a.tilt.counts_min, a.tilt.counts_max) == (0.580, 0.730, 26, 917)
    assert (a.top.min, a.top.max, a.top.counts_min, a.top.counts_max) == (0.655, 0.905, 26, 255)
    assert (a.right.min, a.right.max, a.right.counts_min, a.right.counts_max) == (0.500, 0.575, 26, 503)
    assert (a.left.min, a.left.max, a.left.counts_min, a.left.counts_max) == (0.500, 0.580, 30, 510)
    assert (a.lift.min, a.lift.max, a.lift.counts_min, a.lift.counts_max) == (-0.223, 0.663, 26, 255)
    assert [getattr(a, n).valve_multiplier for n in ("tilt", "top", "lift", "right", "left")] == [0.5, 0.5, 1, 0.2, 0.2]
    assert (a.left.kv_pos, a.left.kv_neg, a.lift.dead_zone, a.tilt.transport_delay) == (1.1085, 1.246, 6, 0.1)
    # table 3-7 and §3.2 limits
    assert p.workspace.thesis_box.z == (-0.330, 0.330)
    assert (p.limits.top_link_yaw_max, p.limits.top_link_pitch_up_max) == (0.15, 0.35)
    assert "thesis-t132" in available_profiles()


def _mutate(raw, path, value):
    d = copy.deepcopy(raw)
    node = d
    for k in path[:-1]:
        node = node[k]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return d


@pytest.mark.parametrize(
    "path, value, expect",
    [
        (("geometry", "lower_link_length"), -0.96, r"geometry\.lower_link_length = -0\.96: .*allowed: > 0"),
        (("geometry", "lower_link_length"), "long", r"geometry\.lower_link_length = 'long'"),
        (("geometry", "lift_arm_length"), 0.0, r"geometry\.lift_arm_length = 0\.0"),
        (("geometry", "pivot_height"), KeyError, r"geometry\.pivot_height: Field required"),
        (("geometry", "colour"), "red", r"geometry\.colour = 'red': unknown key"),
        (("geometry", "lift_arm_pivot"), [0.0, 1.0], r"geometry\.lift_arm_pivot"),
        (
            ("geometry", "limiter_tractor_point"),
            [0.0, math.inf, 0.0],
            r"geometry\.limiter_tractor_point\.1 = inf: Input should be a finite number",
        ),
        (("actuators", "tilt", "min"), 0.9, r"actuators\.tilt: .*min < max"),
        (
            ("actuators", "tilt", "counts_max"),
            2000,
            r"actuators\.tilt\.counts_max = 2000: .*allowed: >= 0 and <= 1023 counts\)",
        ),
        (("actuators", "lift", "max"), 2.0, r"actuators\.lift\.max = 2\.0: .*allowed: > -1\.5708 and < 1\.5708 rad"),
        # a 1-count sensor loaded and failed in the twin: "relay_margin_counts = 2 leaves no stroke (span 1 counts)"
        (("actuators", "lift", "counts_max"), 29, r"actuators\.lift: .*over at least 16 counts"),
        (("actuators", "tilt", "neutral"), 0.9, r"actuators\.tilt: .*neutral = 0\.9 m must lie within the stroke"),
        (("actuators", "top", "valve_multiplier"), 0.0, r"actuators\.top\.valve_multiplier = 0\.0"),
        (
            ("limits", "top_link_yaw_max"),
            2.0,
            r"limits\.top_link_yaw_max = 2\.0: .*allowed: > 0 and <= 1\.5708 rad; did you mean degrees\? 2 deg",
        ),
        (("limits", "top_link_angle_reference"), "sky", r"limits\.top_link_angle_reference = 'sky'"),
        (("workspace", "z_reference"), "sea", r"workspace\.z_reference = 'sea'"),
        (("workspace", "thesis_box", "roll"), [-4.0, 4.0], r"workspace\.thesis_box: .*within ±π"),
        (("workspace", "thesis_box", "x"), [0.1, -0.1], r"workspace\.thesis_box: .*min < max"),
        (("implement", "default_category"), "7", r"implement: .*default_category '7' is not one of"),
        (
            ("implement", "categories", "2", "span"),
            -1,
            r"implement\.categories\.2\.span = -1: .*allowed: > 0 and <= 2 m\)",
        ),
        (("schema_version",), 2, r"schema_version = 2"),
        (("name",), "bad name!", r"name = 'bad name!'"),
    ],
)
def test_validation_errors_name_field_value_and_range(raw, path, value, expect):
    with pytest.raises(ProfileError, match=expect):
        profile_from_dict(_mutate(raw, path, value), source="test")


@pytest.mark.parametrize(
    "path, value, expect",
    [
        # a member length typed in mm: "allowed: > 0 and <= 3", no unit (a reviewer's note on lag in mm)
        (("geometry", "lower_link_length"), 960.0, "allowed: > 0 and <= 3 m; did you mean mm? 960 mm = 0.96 m)"),
        (("limits", "top_link_yaw_max"), 30.0, "allowed: > 0 and <= 1.5708 rad; did you mean degrees? 30 deg"),
        (("motion", "final_approach"), {"x": 2.5, "z": 0.004, "roll": 0.005, "pitch": 0.007}, "<= 0.05 m; did you"),
        (
            ("motion", "final_approach"),
            {"x": 0.0025, "z": 0.004, "roll": 0.005, "pitch": 0.007, "lag": {"x": 0, "z": 0, "roll": 2.0, "pitch": 0}},
            "final_approach.lag.roll = 2.0: Input should be less than or equal to 0.02 (allowed: >= -0.01 and <= "
            "0.02 rad; did you mean mrad? 2 mrad = 0.002 rad)",
        ),
        (("stability", "jog_horizon"), 600.0, "(allowed: > 0 and <= 5 s)"),
        (("actuators", "tilt", "valve_multiplier"), 2.0, "(allowed: > 0 and <= 1)"),  # a ratio: no unit
        # a front ballast in tonnes: taken as 0.9 kg before (a user trial)
        (
            ("stability", "front_ballast"),
            0.9,
            "stability.front_ballast = 0.9: must be 0 (no ballast) or more than 5 kg (allowed: >= 0 and <= 5000 kg; "
            "did you mean t? 0.9 t = 900 kg)",
        ),
        (("stability", "front_ballast"), 6000.0, "(allowed: >= 0 and <= 5000 kg)"),  # 6 t is beyond it too: no hint
    ],
)
def test_a_value_out_of_range_is_named_with_its_unit_and_a_unit_slip_is_offered(raw, path, value, expect):
    with pytest.raises(ProfileError) as err:
        profile_from_dict(_mutate(raw, path, value), source="test")
    assert expect in str(err.value)


def test_file_errors(tmp_path):
    with pytest.raises(ProfileError, match="not found; built-in profiles: .*thesis-t132"):
        load_profile("no-such-profile")
    with pytest.raises(ProfileError, match="does not exist"):
        load_profile(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("this is = = not toml")
    with pytest.raises(ProfileError, match="not valid TOML"):
        load_profile(bad)


def test_a_profile_with_a_byte_order_mark_loads(tmp_path):
    """An attacker's report (on a field file): a UTF-8 byte-order mark, as Windows editors write, was "not valid
    TOML: Invalid statement (at line 1, column 1)"; every text file is read through the same reader."""
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + (resources.files("planner") / "profiles" / "thesis-t132.toml").read_bytes())
    assert load_profile(path) == load_profile("thesis-t132")


def test_profile_file_round_trip(tmp_path, raw):
    import tomllib as _t

    path = tmp_path / "copy.toml"
    path.write_bytes((resources.files("planner") / "profiles" / "thesis-t132.toml").read_bytes())
    assert load_profile(path) == load_profile("thesis-t132")
    assert _t.loads(path.read_text()) == raw


def test_unknown_category_names_the_allowed_ones():
    with pytest.raises(ProfileError, match="allowed: 1N, 1, 2N, 2, 3N, 3, 4N, 4"):
        load_profile().category("5")


# -- a profile that cannot work is refused where it is loaded, naming the field (a new user's report: each of
# these loaded and failed at the first plan or at `hitch serve` with "exceed stroke:top:max at t = 0.00 s",
# "closure error 1.62e+05 m", "top_link_yaw_min at t = 2.38 s" or the Guard's "tractor profile file ... does
# not exist")
def _model(raw, path, value):
    from planner.model.kinematics import HitchModel

    return HitchModel(profile_from_dict(_mutate(raw, path, value), source="test"))


def test_a_stroke_that_misses_the_neutral_pose_is_refused_naming_it(raw):
    with pytest.raises(ProfileError, match=r"needs top = 0\.\d+ m, outside its stroke actuators\.top \[0\.5, 0\.6\]"):
        _model(raw, ("actuators", "top"), {**raw["actuators"]["top"], "min": 0.5, "max": 0.6})


def test_a_ground_clearance_the_neutral_pose_breaks_is_refused_naming_it(raw):
    with pytest.raises(ProfileError, match=r"breaks limits\.ground_clearance: the lower link ends are .* m above"):
        _model(raw, ("limits", "ground_clearance"), 1.5)


def test_a_workspace_box_in_mm_or_for_an_unknown_category_is_refused(raw):
    box = {**raw["workspace"]["restricted"]["2"], "z": [-203.4, 351.0]}
    with pytest.raises(ProfileError, match=r"z = \[-203\.4, 351\.0\]: bounds are in m .*did you mean mm\?"):
        profile_from_dict(_mutate(raw, ("workspace", "restricted", "2"), box), source="test")
    with pytest.raises(ProfileError, match=r"thesis_box.*did you mean mm\?"):
        profile_from_dict(_mutate(raw, ("workspace", "thesis_box", "z"), [-330, 330]), source="test")
    extra = _mutate(raw, ("workspace", "restricted", "7"), raw["workspace"]["restricted"]["2"])
    with pytest.raises(ProfileError, match=r"workspace\.restricted: no category '7' in implement\.categories"):
        profile_from_dict(extra, source="test")


def test_a_workspace_box_wider_than_the_mechanism_is_refused_naming_it(raw):
    from planner.model.kinematics import HitchModel
    from planner.trajectory import PlanError, TrajectoryPlanner

    box = {**raw["workspace"]["restricted"]["2"], "x": [-0.5, 0.5]}
    model = HitchModel(profile_from_dict(_mutate(raw, ("workspace", "restricted", "2"), box), source="test"), "2")
    with pytest.raises(PlanError, match=r"workspace\.restricted\.2 \(x \[-0\.5, 0\.5\].* is not all reachable: at x"):
        TrajectoryPlanner(model)
    TrajectoryPlanner(HitchModel(profile_from_dict(raw, source="test"), "2"))  # the shipped box is


def test_the_tractor_profile_is_checked_at_load_and_a_relative_path_is_the_profile_files(tmp_path, monkeypatch):
    profiles = resources.files("planner") / "profiles"
    text = (profiles / "thesis-t132.toml").read_text()
    assert 'tractor_profile = "tractor-6t"' in text
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "my-tractor.toml").write_bytes((profiles / "tractors" / "tractor-6t.toml").read_bytes())
    prof = tmp_path / "mine" / "hitch.toml"
    prof.write_text(text.replace('tractor_profile = "tractor-6t"', 'tractor_profile = "my-tractor.toml"'))
    monkeypatch.chdir(tmp_path)  # not the profile's folder
    loaded = load_profile(prof)
    assert loaded.stability.tractor_profile == str(tmp_path / "mine" / "my-tractor.toml")
    prof.write_text(text.replace('tractor_profile = "tractor-6t"', 'tractor_profile = "nope.toml"'))
    with pytest.raises(ProfileError, match=r"stability\.tractor_profile = 'nope\.toml': .*does not exist"):
        load_profile(prof)
