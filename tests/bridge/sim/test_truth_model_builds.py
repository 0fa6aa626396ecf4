"""A truth is drawn only from a nominal that loads as ``hitch profile show`` loads it, and only a truth whose
model builds is returned (a commissioning trial: ``sim perturb`` wrote a truth of a profile whose neutral pose
does not close, and ``profile show`` of the truth then failed, "cannot find the neutral pose")."""

from __future__ import annotations

import pytest

from bridge.sim import truth
from bridge.sim.truth import TruthError, perturb_profile
from planner.model.kinematics import HitchModel
from planner.profiles.hitch import Profile, load_profile, profile_from_dict


def _variant(edit) -> Profile:
    data = load_profile("thesis-t132").model_dump(mode="python")
    edit(data)
    return profile_from_dict(data)


def _limiter_behind(data: dict) -> None:  # the trial's slip: the sway-limiter point's x with the wrong sign
    data["geometry"]["limiter_tractor_point"] = (-0.1486666, 0.0, 0.0)


def _top_stroke_just_over_its_neutral(data: dict) -> None:  # the nominal builds; most tape-measured truths do not
    data["actuators"]["top"]["max"] = 0.742683  # the neutral needs 0.742483 m of top link


def test_a_nominal_whose_model_does_not_build_is_refused_with_its_own_error():
    nominal = _variant(_limiter_behind)
    with pytest.raises(TruthError) as err:
        perturb_profile(nominal, 1, source="--profile sign3.toml")
    text = str(err.value)
    assert text.startswith("--profile sign3.toml does not load (category 2): profile thesis-t132: cannot find the ")
    assert "neutral pose" in text and "truth" not in text
    with pytest.raises(TruthError, match=r"^the nominal profile thesis-t132 does not load \(category 2\)"):
        perturb_profile(nominal, 1)


def test_a_drawn_truth_whose_model_does_not_build_is_refused_with_the_reason():
    nominal = _variant(_top_stroke_just_over_its_neutral)
    HitchModel(nominal)  # the nominal builds
    with pytest.raises(TruthError) as err:
        perturb_profile(nominal, 3)
    text = str(err.value)
    assert text.startswith("the drawn truth thesis-t132-truth-3 (seed 3) does not load (category 2): ")
    assert "needs top = 0.7531 m, outside its stroke actuators.top [0.655, 0.742683] m" in text
    assert "the draw is refused, nothing is written (draw another seed)" in text
    data, _ = perturb_profile(nominal, 0)  # another seed's truth builds
    HitchModel(profile_from_dict(data))


def test_check_model_builds_passes_a_profile_that_builds():
    truth.check_model_builds(load_profile("thesis-t132"), "thesis")
