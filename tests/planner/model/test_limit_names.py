"""Limit names as values: ``str(LimitName.parse(s)) == s`` for every name the planner produces,
collected from the code that produces them (hard limits, the SQP layout, plan verification,
kinematic margins, jog flags, the guard), and malformed names are refused."""

from __future__ import annotations

import numpy as np
import pytest

from planner.errors import HitchInputError
from planner.ik_qp.hitch_ik import IKSolver
from planner.ik_qp.hitch_mechanism import build_hitch_mechanism
from planner.ik_qp.result import Target
from planner.limits.guard import _END_STOP_NAMES, Guard
from planner.limits.kinematic_margin import kinematic_margin
from planner.model.hard_limits import FEATURE_LIMIT_ROWS, STROKE_NAMES, HardLimits
from planner.model.limit_names import LimitName, LimitNameError
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES
from planner.trajectory.actuator_limits import ActuatorLimits
from planner.trajectory.jog import JogController
from planner.trajectory.plan import MotionState, Setpoints, verify_setpoints
from planner.trajectory.planner import TrajectoryPlanner


@pytest.fixture(scope="module")
def planner_(model):
    return TrajectoryPlanner(model)


def _hard_limit_names(model) -> set[str]:
    hard = HardLimits.from_model(model)
    q_low, q_high = hard.actuator_lower - 1.0, hard.actuator_upper + 1.0
    f_low, f_high = np.full(11, -np.inf), np.full(11, np.inf)
    f_mid = np.zeros(11)
    f_mid[list(hard.feature_index)] = hard.feature_upper + 1.0  # finite upper bounds only
    names = set(hard.violations(q_low, f_low)) | set(hard.violations(q_high, f_mid))
    names |= {n for n in (*hard.names_lower, *hard.names_upper) if n}
    assert set(hard.violations(q_high, f_high)) >= {n for _, n in STROKE_NAMES}
    return names


def _sqp_names(model) -> set[str]:
    ik = IKSolver(model, use_workspace=True)
    res = ik.solve(Target(0.5, model.neutral_pose.z, 0.0, 0.0))  # far out in x: limited by the workspace
    assert res.status == "limited" and "workspace:x:max" in res.active
    names = set(res.active) | set(res.extra["at_bound"])
    for lay in ik.sqp._layouts.values():
        names |= {n for n in (*lay.names_min, *lay.names_max, *lay.row_names) if n}
    for pair in build_hitch_mechanism(model).limit_names():
        names |= set(pair)
    return names


def _verification_names(model) -> set[str]:
    q = np.tile(model.neutral, (3, 1))
    qd = np.array([np.zeros(5), np.full(5, 1e3), np.full(5, -1e3)])
    sp = Setpoints(50.0, np.array([0.0, 0.02, 0.04]), np.zeros((3, 6)), np.zeros((3, 4)), q, qd)
    names = {
        v.limit
        for v in verify_setpoints(sp, model, HardLimits.from_model(model), ActuatorLimits.from_profile(model.profile))
    }
    assert {f"velocity:{a}" for a in ACTUATOR_NAMES} | {f"acceleration:{a}" for a in ACTUATOR_NAMES} <= names
    return names


def _margin_names(model, tp) -> set[str]:
    hard = HardLimits.from_model(model)
    q = model.neutral
    f, jac = model.features(q)
    names = set()
    for k in range(4):
        for sign in (1.0, -1.0):
            pv = np.zeros(4)
            pv[k] = sign
            km = kinematic_margin(f[[0, 2, 3, 4]], pv, q, np.zeros(5), f, np.zeros(11), hard, tp.workspace)
            names |= {d["limit"] for d in km.per_dof.values() if d["limit"]}
    for i in range(5):
        for sign in (1.0, -1.0):
            qd = np.zeros(5)
            qd[i] = sign
            names.add(kinematic_margin(np.zeros(4), np.zeros(4), q, qd, f, np.zeros(11), hard, None).limit)
    for row in hard.feature_index:
        for sign in (1.0, -1.0):
            fr = np.zeros(11)
            fr[row] = sign
            names.add(kinematic_margin(np.zeros(4), np.zeros(4), q, np.zeros(5), f, fr, hard, None).limit)
    names.discard("")  # moving away from every limit: no name
    assert {f"workspace:{k}:{s}" for k in CONTROLLED_POSE_NAMES for s in ("min", "max")} <= names
    return names


def _jog_names(tp) -> set[str]:
    names = set()
    for k in range(4):
        for face, sign in ((tp.hi, 1.0), (tp.lo, -1.0)):
            p = (tp.lo + tp.hi) / 2
            p[k] = face[k]
            jog = JogController(tp, MotionState.at_rest(p))
            rates = np.zeros(4)
            rates[k] = sign * 0.01
            names |= set(jog.clipped_rates(rates)[1].values())
    assert len(names) == 8
    return names


def _guard_names(tp) -> set[str]:
    guard = Guard(tp)
    return set(_END_STOP_NAMES) | set(guard._keep_out_names)


@pytest.fixture(scope="module")
def produced(model, planner_) -> list[str]:
    names = (
        _hard_limit_names(model)
        | _sqp_names(model)
        | _verification_names(model)
        | _margin_names(model, planner_)
        | _jog_names(planner_)
        | _guard_names(planner_)
    )
    return sorted(names)


def test_every_produced_name_round_trips(produced):
    assert len(produced) > 40
    for text in produced:
        name = LimitName.parse(text)
        assert str(name) == text, (text, name)
        assert LimitName.parse(str(name)) == name


def test_the_produced_names_are_the_documented_ones(produced):
    kinds = {LimitName.parse(n).kind for n in produced}
    assert {"stroke", "workspace", "velocity", "acceleration", "end_stop", "keep_out"} <= kinds
    assert {"top_link_yaw", "top_link_pitch", "ground_clearance"} <= kinds
    assert {r[1] for r in FEATURE_LIMIT_ROWS} | {r[2] for r in FEATURE_LIMIT_ROWS if r[2]} <= set(produced)


@pytest.mark.parametrize(
    ("text", "fields"),
    [
        ("stroke:lift:min", ("stroke", "lift", "min", False)),
        ("workspace:x:max", ("workspace", "x", "max", False)),
        ("workspace:pitch", ("workspace", "pitch", "", False)),
        ("velocity:top", ("velocity", "top", "", False)),
        ("keep_out:couplers:min", ("keep_out", "couplers:min", "", False)),  # a keep-out name may hold ':'
        ("end_stop:right", ("end_stop", "right", "", False)),
        ("top_link_yaw_min", ("top_link_yaw", "", "min", True)),
        ("top_link_pitch_max", ("top_link_pitch", "", "max", True)),
        ("ground_clearance_left", ("ground_clearance", "left", "", True)),
        ("z_right_end_max", ("z_right_end", "", "max", True)),
        ("implement_rigidity", ("implement_rigidity", "", "", False)),
        ("joint_limit:min", ("joint_limit", "", "min", False)),
    ],
)
def test_parse_takes_a_name_apart(text, fields):
    name = LimitName.parse(text)
    assert (name.kind, name.member, name.side, name.flat) == fields
    assert str(name) == text


def test_constructed_names_spell_as_today():
    assert str(LimitName("stroke", "lift", "min")) == "stroke:lift:min"
    assert str(LimitName("workspace", "x", "max")) == "workspace:x:max"
    assert str(LimitName("ground_clearance", "right", flat=True)) == "ground_clearance_right"
    assert str(LimitName("top_link_yaw", side="max", flat=True)) == "top_link_yaw_max"
    assert str(LimitName("velocity", "lift")) == "velocity:lift"


@pytest.mark.parametrize("text", ["", ":x", "stroke:", "stroke::min", "top_link_yaw_", 3])
def test_malformed_strings_are_refused(text):
    with pytest.raises(LimitNameError):
        LimitName.parse(text)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"kind": ""},
        {"kind": "a:b"},
        {"kind": "stroke", "member": "lift", "side": "up"},
        {"kind": "stroke", "member": "lift", "flat": True},  # only the feature kinds are spelled with '_'
        {"kind": "ground_clearance", "member": "left", "side": "min", "flat": True},
    ],
)
def test_bad_fields_are_refused(kwargs):
    with pytest.raises(LimitNameError) as info:
        LimitName(**kwargs)
    assert isinstance(info.value, HitchInputError) and isinstance(info.value, ValueError)


def test_limit_names_are_values():
    a, b = LimitName("stroke", "lift", "min"), LimitName.parse("stroke:lift:min")
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
