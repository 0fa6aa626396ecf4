"""A profile with the pin play's lag (``motion.final_approach.lag``) in the service: gotos aim the mechanism
beyond the goal by it, and every pose recorded from where the hitch stands is the implement's (the mechanism
less the lag), so going back to it does not move the mechanism one lag further each time.

Truth used: the lag written into the profile; the commanded state (the mechanism) before and after.
"""

from __future__ import annotations

import numpy as np
import pytest

from bridge.service.maneuvers.recorder import recorder_for
from planner.limits.guard import Guard
from planner.limits.implement_limits import ImplementLimits
from planner.model.kinematics import HitchModel
from planner.profiles.hitch import load_profile
from planner.trajectory import MotionState, TrajectoryPlanner
from tests.helpers import SimService, profile_file_with_final_approach

LAG = np.array([0.0005, 0.0008, 0.002, 0.003])  # x, z [m], roll, pitch [rad]
POSE = ("x", "z", "roll", "pitch")
WORK = {"x": 0.02, "z": -0.05, "roll": 0.0, "pitch": 0.0}


def _model(tmp_path, side: str = "below") -> HitchModel:
    prof = profile_file_with_final_approach(tmp_path)
    lag = ", ".join(f"{k} = {v}" for k, v in zip(POSE, LAG, strict=True))
    prof.write_text(prof.read_text() + f'side = "{side}"\nlag = {{ {lag} }}\n')
    return HitchModel(load_profile(str(prof)), "2")


@pytest.fixture
def svc(tmp_path):
    s = SimService(_model(tmp_path), tmp_path / "s.sqlite3")
    s.ok("implements/define", {"name": "harrow", "category": "2", "mass_kg": 1200.0, "com_m": [0.0, 0.6, 0.4]})
    s.ok("implements/select", {"name": "harrow"})
    yield s
    s.close()


def _goto(svc: SimService, key: str, payload: dict | None = None) -> dict:
    r = svc.ok(key, payload)
    svc.run(r["duration"] + 0.5)
    return r


def _mechanism(svc: SimService) -> np.ndarray:
    return svc.mc.current_state().position.copy()


def test_quick_raise_and_return_come_back_to_the_same_mechanism_pose_every_cycle(svc):
    """The work pose a raise records was the mechanism's pose, which a return aimed one lag further: 0.5 mm of
    x, 0.8 mm of z, 2 and 3 mrad more on every headland turn (a reviewer's reproduction)."""
    svc.ok("presets/save", {"name": "headland", "pose": {"x": 0.0, "z": 0.25, "roll": 0.0, "pitch": 0.0}})
    _goto(svc, "goto", {"goal": WORK})
    first = _mechanism(svc)
    assert first == pytest.approx(np.array(list(WORK.values())) + LAG, abs=1e-9)  # aimed beyond by the lag
    for _ in range(3):
        r = _goto(svc, "hitch/raise")
        assert r["last_work"] == pytest.approx(WORK, abs=1e-9)  # the implement's pose, not the mechanism's
        _goto(svc, "hitch/return")
        assert _mechanism(svc) == pytest.approx(first, abs=1e-9)


def test_a_preset_saved_where_the_hitch_stands_brings_it_back_there(svc):
    _goto(svc, "goto", {"goal": WORK})
    here = _mechanism(svc)
    saved = svc.ok("presets/save", {"name": "here"})
    assert saved["pose"] == pytest.approx(WORK, abs=1e-9)
    _goto(svc, "goto", {"goal": {"z": 0.1}})
    _goto(svc, "presets/go", {"name": "here"})
    assert _mechanism(svc) == pytest.approx(here, abs=1e-9)


def test_a_taught_pose_is_the_implement_s(svc):
    _goto(svc, "goto", {"goal": WORK})
    pose = recorder_for(svc.mc).pose()
    assert [pose[k] for k in POSE] == pytest.approx(list(WORK.values()), abs=1e-9)


@pytest.mark.parametrize("side", ["below", "above"])
def test_a_goal_at_the_implement_s_upper_height_is_not_refused_and_the_cut_lag_is_named(tmp_path, side):
    """The aim above the goal by the lag went over the implement's upper height: a goto to exactly that height
    (a headland preset there) was refused (a reviewer's reproduction). The aim and a via from above stay below
    it; the DOF whose lag is cut is named."""
    guard = Guard(TrajectoryPlanner(_model(tmp_path, side)))
    guard.set_implement_limits(ImplementLimits(upper_height_m=0.28))
    start = MotionState.at_rest(np.array([0.0, 0.1, 0.0, 0.0]))
    gp = guard.plan(start, {"z": 0.28})
    fa = gp.plan.info["final_approach"]
    z_max = float(np.max(guard.planner.sample(gp.plan).pose[:, 2]))
    assert z_max <= 0.28 + 1e-9
    if side == "below":  # aimed at the height itself: the implement rests one lag short, said so
        assert fa["aim"][1] == pytest.approx(0.28) and fa["aim_short"] == ["z"]
    else:  # aimed one lag below the goal; the via from above is cut at the height
        assert fa["aim"][1] == pytest.approx(0.28 - LAG[1]) and fa["aim_short"] == [] and "z" in fa["short"]


def test_a_goal_on_a_workspace_face_names_the_dof_whose_lag_the_face_cuts(tmp_path):
    tp = TrajectoryPlanner(_model(tmp_path))
    start = MotionState.at_rest(tp.model.neutral_pose.controlled())
    plan = tp.plan_move(start, {"pitch": float(tp.hi[3]), "z": 0.1})
    assert plan.info["final_approach"]["aim_short"] == ["pitch"]
    plan = tp.plan_move(start, {"pitch": float(tp.hi[3]) - 0.01, "z": 0.1})
    assert plan.info["final_approach"]["aim_short"] == []
