"""A geometry whose neutral pose does not close, or puts the top link beyond its stroke, is refused naming the
profile field (TOML path), the value given and the range of that field (the others as given) that loads, in m
(a user trial: an engineer editing a copy of the thesis profile got "top link cannot reach the implement mast
with this length (circle-sphere miss, cos argument -1.157)" for a 1.9 m mast and "left lift rod cannot reach the
left lower link (closure error 0.00048 m)" for a 1.9 m span, neither naming the field nor a range).

Each stated bound is checked: it is rounded inward to 0.1 mm, so the bound and a value 1 mm inside it load and
a value 0.2 mm outside (beyond the true edge, which lies less than 0.1 mm past the bound) is refused."""

from __future__ import annotations

import copy
import re
import tomllib
from importlib import resources

import pytest

from planner.errors import HitchError
from planner.model.kinematics import HitchModel
from planner.model.types import KinematicsError
from planner.profiles.hitch import ProfileError, profile_from_dict


@pytest.fixture(scope="module")
def raw() -> dict:
    return tomllib.loads((resources.files("planner") / "profiles" / "thesis-t132.toml").read_text())


def _model(raw: dict, category: str, **fields: float) -> HitchModel:
    data = copy.deepcopy(raw)
    data["implement"]["categories"][category].update(fields)
    return HitchModel(profile_from_dict(data), category)


def _refusal(raw: dict, category: str, **fields: float) -> HitchError:
    with pytest.raises(HitchError) as err:
        _model(raw, category, **fields)
    return err.value


def test_a_span_the_lower_links_cannot_reach_names_the_field_and_the_spans_they_reach(raw):
    for category in ("2", "4"):  # with a restricted workspace and without
        exc = _refusal(raw, category, span=1.9)
        assert isinstance(exc, KinematicsError)
        text = str(exc)
        assert text.startswith(
            f"profile thesis-t132: cannot find the neutral pose: implement.categories.{category}.span = 1.9 m: the "
            "lower links cannot reach this span with lift and tilt at their neutrals"
        )
        assert "KinematicsError" not in text and "\n" not in text
        found = re.search(rf"implement\.categories\.{category}\.span must be at most (\d\.\d{{4}}) m \(ISO 730", text)
        assert found, text
        assert "ball centres are implement.ball_centre_correction = 0.04 m wider" in text
    top = float(found.group(1))
    # category 4 has no restricted workspace: everything the links reach loads (the top link may leave its stroke)
    for span in (top, top - 0.001):
        assert _model(raw, "4", span=span).span == pytest.approx(span + 0.04)
    assert "span must be at most" in str(_refusal(raw, "4", span=top + 0.0002))


def test_a_mast_the_top_link_holds_only_beyond_its_stroke_names_the_masts_it_holds(raw):
    exc = _refusal(raw, "2", mast_height=1.9)
    assert isinstance(exc, ProfileError)
    text = str(exc)
    assert "needs top = 1.6556 m, outside its stroke actuators.top [0.655, 0.905] m" in text
    assert "cos argument" not in text and "KinematicsError" not in text
    found = re.search(r"or implement\.categories\.2\.mast_height = 1\.9 m must be at most (\d\.\d{4}) m \(", text)
    assert found, text
    top = float(found.group(1))
    assert 0.9 < top < 1.0
    for mast in (top, top - 0.001, 0.36):
        assert _model(raw, "2", mast_height=mast).mast_height == mast
    assert "must be at most" in str(_refusal(raw, "2", mast_height=top + 0.0002))


def test_a_tall_mast_without_a_workspace_closes_with_a_long_top_link(raw):
    """The neutral pose needs only a longer top link: it was refused as "top link cannot reach the implement mast"
    (the solve started the top link mid-stroke), as category 4 with its 1.1 m mast is not."""
    model = _model(raw, "4", mast_height=1.9)
    assert model.neutral[2] > model.upper[2]
    assert model.forward(model.neutral).pose.pitch == pytest.approx(0.0, abs=1e-12)


def test_the_neutral_pose_of_the_thesis_profile_is_unchanged(model):
    assert model.neutral[3] == pytest.approx((0.540 + 0.5375) / 2, abs=1e-6)
    s = model.forward(model.neutral)
    assert (s.pose.x, s.pose.pitch) == pytest.approx((0.0, 0.0), abs=1e-12)
    assert s.lower_span == pytest.approx(0.825 + 0.040, abs=1e-12)
