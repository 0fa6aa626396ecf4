"""Profile slips of a commissioning trial: each error names the field (dotted path), the value given and what
is allowed, with the unit and the unit slip it likely is, and blames the field that is wrong.

The trial's profile loaded with (before these tests): a top-link stroke in mm named no field, no value and no
"did you mean mm?"; a tilt stroke in mm blamed the (right) neutral; a lift stroke in degrees named nothing; a
reversed sensor (counts_min 917, counts_max 26) said "at least 16 counts apart" of an 891-count span; NaN said
"Input should be less than or equal to 3"; a sway-limiter point on the pivot loaded and failed later with
"reachable 0.6129..0.6129 m (closure error nan m)".
"""

from __future__ import annotations

import copy
import math
import tomllib
from importlib import resources
from pathlib import Path

import pytest
from pydantic import BaseModel, Field, ValidationError

from planner.profiles.hitch import ProfileError, load_profile, profile_from_dict, write_profile_text
from planner.profiles.loader import format_validation_error


@pytest.fixture(scope="module")
def raw() -> dict:
    return tomllib.loads((resources.files("planner") / "profiles" / "thesis-t132.toml").read_text())


def _error(raw: dict, edits: dict[tuple[str, ...], object]) -> str:
    data = copy.deepcopy(raw)
    for path, value in edits.items():
        node = data
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = value
    with pytest.raises(ProfileError) as err:
        profile_from_dict(data, source="test")
    return str(err.value)


def test_a_top_link_stroke_in_mm_is_named_with_its_value_range_and_the_mm_reading(raw):
    text = _error(raw, {("actuators", "top", "min"): 655})
    assert (
        "actuators.top.min = 655: Input should be less than or equal to 5 (allowed: > 0 and <= 5 m; "
        "did you mean mm? 655 mm = 0.655 m)" in text
    )
    text = _error(raw, {("actuators", "top", "min"): 655, ("actuators", "top", "max"): 905})
    assert "actuators.top.min = 655" in text and "actuators.top.max = 905" in text and "905 mm = 0.905 m" in text


def test_a_tilt_stroke_in_mm_is_blamed_not_the_neutral_inside_the_real_stroke(raw):
    text = _error(raw, {("actuators", "tilt", "min"): 580, ("actuators", "tilt", "max"): 730})
    assert raw["actuators"]["tilt"]["neutral"] == 0.630  # a neutral in m, right for the stroke in m
    assert "actuators.tilt.min = 580" in text and "did you mean mm? 580 mm = 0.58 m" in text
    assert "actuators.tilt.max = 730" in text and "730 mm = 0.73 m" in text
    assert "neutral" not in text


@pytest.mark.parametrize(
    "key, value, words",
    [
        ("max", 38, "actuators.lift.max = 38: Input should be less than 1.5707963267948966 (allowed: > -1.5708 and "
         "< 1.5708 rad; did you mean degrees? 38 deg = 0.663225 rad"),
        ("min", -12.8, "actuators.lift.min = -12.8: Input should be greater than -1.5707963267948966 (allowed: > "
         "-1.5708 and < 1.5708 rad; did you mean degrees? -12.8 deg = -0.223402 rad"),
    ],
)  # fmt: skip
def test_a_lift_stroke_in_degrees_is_named_with_its_value_range_and_the_degrees_reading(raw, key, value, words):
    assert words in _error(raw, {("actuators", "lift", key): value})


def test_a_neutral_in_the_wrong_unit_is_named_with_its_unit_and_reading(raw):
    text = _error(raw, {("actuators", "tilt", "neutral"): 630})
    assert "actuators.tilt: neutral = 630 m must lie within the stroke [min, max] = [0.58, 0.73] m" in text
    assert "did you mean mm? 630 mm = 0.63 m" in text
    text = _error(raw, {("actuators", "lift", "neutral"): 12.6})
    assert "actuators.lift: neutral = 12.6 rad must lie within the stroke" in text
    assert "did you mean degrees? 12.6 deg = 0.219911 rad" in text


def test_a_reversed_sensor_is_called_reversed_not_too_short(raw):
    text = _error(raw, {("actuators", "tilt", "counts_min"): 917, ("actuators", "tilt", "counts_max"): 26})
    assert "actuators.tilt: counts_min = 917 must be below counts_max = 26" in text
    assert "reversed (swap them)" in text
    text = _error(raw, {("actuators", "tilt", "counts_max"): 26})  # equal: not reversed, not a span either
    assert "counts_min = 26 must be below counts_max = 26" in text and "reversed" not in text
    # a short span in the right order keeps its own message
    assert "over at least 16 counts" in _error(raw, {("actuators", "tilt", "counts_max"): 30})


def test_a_reversed_stroke_names_min_and_max_with_the_unit(raw):
    text = _error(raw, {("actuators", "top", "min"): 0.905, ("actuators", "top", "max"): 0.655})
    assert "actuators.top: stroke needs min < max (got min = 0.905 m, max = 0.655 m)" in text


@pytest.mark.parametrize(
    "path, value, words",
    [
        (("geometry", "lift_arm_length"), math.nan, "geometry.lift_arm_length = nan: Input should be a finite number "
         "(allowed: > 0 and <= 3 m)"),
        (("geometry", "lift_arm_length"), math.inf, "geometry.lift_arm_length = inf: Input should be a finite number "
         "(allowed: > 0 and <= 3 m)"),
        (("geometry", "lift_arm_length"), -math.inf, "geometry.lift_arm_length = -inf: Input should be a finite "
         "number (allowed: > 0 and <= 3 m)"),
        (("actuators", "top", "max"), math.inf, "actuators.top.max = inf: Input should be a finite number (allowed: "
         "> 0 and <= 5 m)"),
        (("actuators", "tilt", "neutral"), math.nan, "actuators.tilt.neutral = nan: Input should be a finite number"),
        (("geometry", "lift_arm_pivot"), [0.0, math.nan, 0.58], "geometry.lift_arm_pivot.1 = nan: Input should be a "
         "finite number"),
    ],
)  # fmt: skip
def test_nan_and_infinity_are_named_as_not_finite_with_the_range(raw, path, value, words):
    text = _error(raw, {path: value})
    assert words in text
    assert "less than" not in text and "greater than" not in text


def test_nan_from_a_toml_file_is_named_as_not_finite(tmp_path):
    text = (resources.files("planner") / "profiles" / "thesis-t132.toml").read_text()
    path = tmp_path / "nan.toml"
    path.write_text(text.replace("lift_arm_length = 0.300", "lift_arm_length = nan", 1))
    with pytest.raises(ProfileError, match=r"geometry\.lift_arm_length = nan: Input should be a finite number "):
        load_profile(path)


def test_the_loader_names_nan_as_not_finite_where_a_schema_lets_it_through():
    """Arm, tractor and other schemas share the formatter: a NaN failing a bound is named as not finite."""

    class Spec(BaseModel):
        length: float = Field(json_schema_extra={"unit": "m"}, gt=0, le=3.0)

    with pytest.raises(ValidationError) as err:
        Spec.model_validate({"length": math.nan})
    text = format_validation_error("thing", "test", err.value, Spec)
    assert "length = nan: Input should be a finite number (allowed: > 0 and <= 3 m)" in text


def test_a_sway_limiter_point_on_the_lower_link_pivot_is_refused_as_degenerate(raw):
    text = _error(raw, {("geometry", "limiter_tractor_point"): [0.0, 0.0, 0.0]})
    assert "geometry: limiter_tractor_point = [0, 0, 0] m lies on the lower-link pivot" in text
    assert "same length at every sway" in text and "0.6129 m" in text and "at least 0.001 m from the pivot" in text
    assert "nan" not in text
    profile_from_dict(  # a point off the pivot loads (whether the limiters then reach is the model's to say)
        {**raw, "geometry": {**raw["geometry"], "limiter_tractor_point": [0.002, 0.0, 0.0]}}
    )


def test_a_coordinate_in_mm_names_the_point_its_value_and_the_mm_reading(raw):
    text = _error(raw, {("geometry", "lift_arm_pivot"): [0.0, -150.0, 580.0]})
    assert "geometry: lift_arm_pivot = [0, -150, 580]: coordinates are in m and must be finite numbers" in text
    assert "within ±5 m; did you mean mm? 580 mm = 0.58 m" in text


def test_write_profile_text_writes_nothing_a_check_refuses(tmp_path):
    text = (resources.files("planner") / "profiles" / "thesis-t132.toml").read_text()
    out = tmp_path / "out.toml"

    def refuse(prof):
        raise ProfileError(f"profile {prof.name}: cannot find the neutral pose")

    with pytest.raises(ProfileError, match=r"out\.toml was not written: profile thesis-t132: cannot find"):
        write_profile_text(out, text, check=refuse)
    assert sorted(Path(tmp_path).iterdir()) == []
    seen = []
    prof = write_profile_text(out, text, check=seen.append)
    assert seen == [prof] and load_profile(out) == prof


@pytest.mark.parametrize(
    ("centre", "words"),
    [
        ([0.0, 300, 860], "did you mean mm? 860 mm = 0.86 m"),
        ([0, 1e6, -1e6], "within ±5 m"),
        ([0.0, 0.3, 5.5], "within ±5 m"),
    ],
)
def test_a_keep_out_centre_out_of_range_is_refused_with_its_field_range_and_mm_reading(raw, centre, words):
    """A keep-out centre in mm loaded and put the coupler sphere hundreds of metres away (keep-out silently off)."""
    data = copy.deepcopy(raw)
    data["limits"]["keep_out"][0]["centre"] = centre
    with pytest.raises(ProfileError) as err:
        profile_from_dict(data, source="test")
    text = str(err.value)
    assert "limits.keep_out.0.centre" in text
    assert "coordinates are in m" in text and "±5 m" in text
    assert words in text


def test_a_keep_out_centre_in_metres_still_loads(raw):
    data = copy.deepcopy(raw)
    data["limits"]["keep_out"][0]["centre"] = [0.0, 0.3, 0.86]
    assert profile_from_dict(data, source="test").limits.keep_out[0].centre == (0.0, 0.3, 0.86)


def test_a_lower_link_shorter_than_the_points_on_it_names_the_fields_and_their_ranges(raw):
    """A user trial: lower_link_length = 0.2 was refused as "lift_rod_attachment must lie on the lower link
    (< lower_link_length)", naming neither the value nor a range. The ranges stated load; their ends do not."""
    text = _error(raw, {("geometry", "lower_link_length"): 0.2})
    assert (
        "geometry: lift_rod_attachment = 0.3 m and limiter_bracket_position = 0.54 m lie beyond the end of the "
        "lower link, lower_link_length = 0.2 m (points on it are measured along it from its pivot): with the other "
        "fields as given, lower_link_length must be within (0.54, 3] m, or lift_rod_attachment and "
        "limiter_bracket_position within (0, 0.2) m"
    ) in text
    text = _error(raw, {("geometry", "limiter_bracket_position"): 1.2})
    assert (
        "geometry: limiter_bracket_position = 1.2 m lies beyond the end of the lower link, lower_link_length = "
        "0.96 m (points on it are measured along it from its pivot): with the other fields as given, "
        "lower_link_length must be within (1.2, 3] m, or limiter_bracket_position within (0, 0.96) m"
    ) in text
    assert "lift_rod_attachment" not in text

    def geometry(**fields: float) -> dict:
        data = copy.deepcopy(raw)
        data["geometry"].update(fields)
        return data

    from planner.model.kinematics import HitchModel  # the geometry closes over the range (category 4: no stroke check)

    for length in (0.5401, 3.0):
        assert HitchModel(profile_from_dict(geometry(lower_link_length=length)), "4").neutral is not None
    assert "lower_link_length must be within (0.54, 3] m" in _error(raw, {("geometry", "lower_link_length"): 0.54})
    for position in (0.9599, 0.001):
        profile_from_dict(geometry(limiter_bracket_position=position))
    assert "within (0, 0.96) m" in _error(raw, {("geometry", "limiter_bracket_position"): 0.96})
    profile_from_dict(geometry(limiter_bracket_position=1.2, lower_link_length=1.2001))
