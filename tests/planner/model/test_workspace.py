"""The profile's restricted workspace lies inside the reachable set and is maximal."""

import numpy as np
import pytest

from planner.model.kinematics import HitchModel
from planner.model.types import KinematicsError
from planner.model.workspace import Reachability, box_grid, fit_restricted_box

CATS = ["1N", "1", "2N", "2", "3N", "3", "4N"]


@pytest.mark.parametrize("category", CATS)
def test_stored_box_is_reachable_everywhere(category):
    m = HitchModel.from_profile(category=category)
    reach = Reachability(m)
    box = m.workspace
    for t in box_grid(box, 5):
        ok, why = reach.check(t)
        assert ok, (t, why)
    rng = np.random.default_rng(7)
    lo = np.array([box[k][0] for k in ("x", "z", "roll", "pitch")])
    hi = np.array([box[k][1] for k in ("x", "z", "roll", "pitch")])
    for _ in range(500):
        t = lo + (hi - lo) * rng.random(4)
        assert reach(t), t


def test_default_box_is_maximal_and_inside_the_thesis_box(model):
    """Each face either sits on the thesis box or cannot move out by 2 growth steps."""
    reach = Reachability(model)
    box, outer = model.workspace, model.thesis_box()
    for k in ("x", "z", "roll", "pitch"):
        step = 0.01 * (outer[k][1] - outer[k][0])
        assert outer[k][0] - 1e-9 <= box[k][0] and box[k][1] <= outer[k][1] + 1e-9
        for side in (0, 1):
            if abs(box[k][side] - outer[k][side]) < 1e-6:
                continue
            grown = dict(box)
            grown[k] = (box[k][0] - 2 * step, box[k][1]) if side == 0 else (box[k][0], box[k][1] + 2 * step)
            face = {kk: ((grown[k][side],) * 2 if kk == k else grown[kk]) for kk in grown}
            assert not all(reach(t) for t in box_grid(face, 5)), f"{k} face {side} could grow"


def test_fit_reproduces_the_stored_default_box(model):
    res = fit_restricted_box(model)
    for k, (lo, hi) in res.box.items():
        assert lo == pytest.approx(model.workspace[k][0], abs=1e-4)
        assert hi == pytest.approx(model.workspace[k][1], abs=1e-4)
    assert res.stopped_by["x:max"].startswith("top_link_yaw")


def test_category_4_has_no_workspace():
    m = HitchModel.from_profile(category="4")
    assert m.workspace is None
    with pytest.raises(KinematicsError, match="stroke:top:max"):
        fit_restricted_box(m)


def test_literal_interpretation_loses_the_upper_box(model):
    """Taken literally (z from pivot height, top-link angles from the horizontal) the upper
    heights of table 3-7 lie beyond the 0.35 rad upward top-link limit."""
    from planner.profiles.hitch import profile_from_dict

    d = model.profile.model_dump()
    d["limits"]["top_link_angle_reference"] = "horizontal"
    d["workspace"]["z_reference"] = "pivot"
    literal = HitchModel(profile_from_dict(d))
    reach = Reachability(literal)
    assert literal.thesis_box()["z"] == (-0.33, 0.33)
    top = [reach.check(np.array([0.0, 0.33, 0.0, p])) for p in (-0.1, 0.0, 0.1)]
    assert all(not ok and "top_link_pitch_max" in why for ok, why in top)
