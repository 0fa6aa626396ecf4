"""Arm profiles (planner.arm.profile): the shipped worked-example profile and strict validation."""

import math
import tomllib
from importlib import resources

import numpy as np
import pytest

from planner.arm.profile import (
    ArmProfileError,
    arm_profile_from_dict,
    available_arm_profiles,
    load_arm_profile,
)
from planner.arm.transforms import euler_zyz_matrix, homogeneous

H = math.pi / 2


def example_data() -> dict:
    text = (resources.files("planner") / "profiles" / "arms" / "arm-source-example.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def test_example_profile_is_table_2_1_with_the_worked_example_in_metres():
    prof = load_arm_profile("arm-source-example")
    assert "arm-source-example" in available_arm_profiles()
    chain = prof.chain()
    table = [(k.a, k.alpha, k.d, k.theta, k.kind) for k in chain.links]
    assert table == [
        (0.0, H, 0.100, 0.0, "revolute"),  # base height a1 = 100 mm
        (0.100, 0.0, 0.0, 0.0, "revolute"),  # a2 = 100 mm
        (0.0, H, 0.0, H, "revolute"),  # θ3 offset: the source's frame-3 turn
        (0.0, -H, 0.050, 0.0, "revolute"),  # source a3 = 50 mm as d4
        (0.0, H, 0.0, 0.0, "revolute"),
        (0.0, 0.0, 0.020, 0.0, "revolute"),  # tool 20 mm along z6
    ]
    np.testing.assert_array_equal(chain.lower, [-math.pi] * 6)
    np.testing.assert_array_equal(chain.upper, [math.pi] * 6)
    np.testing.assert_array_equal(chain.base, np.eye(4))
    np.testing.assert_array_equal(chain.tool, np.eye(4))


def test_load_from_path_and_frames(tmp_path):
    data = example_data()
    text = (resources.files("planner") / "profiles" / "arms" / "arm-source-example.toml").read_text(encoding="utf-8")
    text += "\n[base]\nposition = [0.5, -0.25, 1.0]\nzyz = [0.3, 0.2, -0.1]\n[tool]\nposition = [0, 0, 0.1]\n"
    path = tmp_path / "my-arm.toml"
    path.write_text(text, encoding="utf-8")
    chain = load_arm_profile(path).chain()
    np.testing.assert_allclose(chain.base, homogeneous(euler_zyz_matrix(0.3, 0.2, -0.1), [0.5, -0.25, 1.0]))
    np.testing.assert_allclose(chain.tool, homogeneous(None, [0, 0, 0.1]))
    assert arm_profile_from_dict(data).chain().n == 6


def test_integers_are_accepted_for_floats():
    data = example_data()
    data["joints"][1]["alpha"] = 0
    assert arm_profile_from_dict(data).joints[1].alpha == 0.0


@pytest.mark.parametrize(
    "mutate, expected",
    [
        (lambda d: d["joints"][0].update(foo=1), r"joints\.0\.foo = 1: unknown key"),
        (lambda d: d["joints"][1].update(a="0.1"), r"joints\.1\.a = '0\.1': Input should be a valid number"),
        (
            lambda d: d["joints"][1].update(a=250.0),
            r"joints\.1\.a = 250\.0: .*a = 250\.0 m is outside the allowed \[-10, 10\] m; did you mean mm\? "
            r"250 mm = 0\.25 m",
        ),
        (lambda d: d["joints"][2].pop("d"), r"joints\.2\.d: Field required"),
        (lambda d: d["joints"][3].update(lower=1.0, upper=0.5), r"joint 'forearm_roll': limits need lower < upper"),
        (lambda d: d["joints"][3].update(upper=7.0), r"upper = 7\.0 rad is outside the allowed ±6\.28319 rad"),
        (lambda d: d["joints"][0].update(d=float("nan")), r"joints\.0\.d = nan: Input should be a finite number"),
        (
            lambda d: d["joints"][0].update(type="helical"),
            r"joints\.0\.type = 'helical': Input should be 'revolute' or 'prismatic'",
        ),
        (lambda d: d["joints"][1].update(name="waist"), r"joint names must be unique; repeated: waist"),
        (lambda d: d.update(schema_version=2), r"schema_version = 2: Input should be 1"),
        (lambda d: d.update(name="bad name!"), r"name = 'bad name!': .*letters, digits"),
        (lambda d: d.update(joints=[]), r"joints = \[\]: .*at least 1 item"),
        (lambda d: d.update(base={"position": [0, 0]}), r"base\.position = \[0, 0\]: .*at least 3 items"),
        (lambda d: d.update(tool={"zyz": [0, 0, 9.0]}), r"tool\.zyz = \[0, 0, 9\.0\]: .*within ±2π rad"),
    ],
)
def test_errors_name_field_value_and_allowed(mutate, expected):
    data = example_data()
    mutate(data)
    with pytest.raises(ArmProfileError, match=expected):
        arm_profile_from_dict(data, source="test")


def test_bad_files_and_names(tmp_path):
    bad = tmp_path / "broken.toml"
    bad.write_text("schema_version = \n", encoding="utf-8")
    with pytest.raises(ArmProfileError, match="not valid TOML"):
        load_arm_profile(bad)
    with pytest.raises(ArmProfileError, match="does not exist"):
        load_arm_profile(tmp_path / "missing.toml")
    with pytest.raises(ArmProfileError, match="built-in arm profiles: arm-source-example"):
        load_arm_profile("arm-nonexistent")
    with pytest.raises(ArmProfileError, match="not found"):
        load_arm_profile("thesis-t132")  # a hitch profile is not an arm profile


def test_millimetres_typed_as_metres_are_refused_with_a_hint():
    data = example_data()
    data["joints"][1].update(a=100.0, d=50.0)  # the source's printed numbers, millimetres
    with pytest.raises(ArmProfileError) as err:
        arm_profile_from_dict(data, source="test")
    text = str(err.value)
    assert "joints.1.a = 100.0: a = 100.0 m is outside the allowed [-10, 10] m; did you mean mm? 100 mm = 0.1 m" in text
    assert "joints.1.d = 50.0: d = 50.0 m is outside the allowed [-10, 10] m; did you mean mm? 50 mm = 0.05 m" in text


@pytest.mark.parametrize(
    "mutate, expected",
    [
        (
            lambda d: d["joints"][4].update(lower=-180.0, upper=180.0),
            r"joint 'wrist_bend': lower = -180\.0 rad is outside the allowed ±6\.28319 rad for a revolute joint; "
            r"did you mean degrees\? -180 deg = -3\.14159 rad",
        ),
        (lambda d: d["joints"][2].update(theta=90.0), r"theta = 90\.0 rad .*did you mean degrees\? 90 deg = 1\.5708"),
        (
            lambda d: d.update(tool={"position": [0, 0, 20.0]}),
            r"tool: position\[2\] = 20\.0 m is outside the allowed ±10 m for the tool; did you mean mm\? 20 mm",
        ),
        (
            lambda d: d.update(base={"position": [0, 0, 250.0]}),
            r"base\.position = .*250\.0 m is outside the allowed ±100 m; did you mean mm\? 250 mm = 0\.25 m",
        ),
    ],
)
def test_unit_slips_get_a_hint(mutate, expected):
    data = example_data()
    mutate(data)
    with pytest.raises(ArmProfileError, match=expected):
        arm_profile_from_dict(data, source="test")


def test_base_may_stand_farther_out_than_a_link_is_long():
    data = example_data()
    data["base"] = {"position": [50.0, -20.0, 1.0]}
    data["joints"][1]["a"] = 10.0
    arm_profile_from_dict(data)
