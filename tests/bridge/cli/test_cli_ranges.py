"""Input ranges of the offline commands ``fk``, ``stability`` and ``plan`` (bridge.cli.ranges).

Truth: the project rule — bad input is refused before any kinematics runs, with one line naming
every violated field, its value and the allowed range (the profile's strokes for ``fk``, the
restricted workspace for poses) and the service's unit hint when value/1000 (mm) or the value in
degrees would fit; never the mechanism's closure error. Ranges are the built-in profile
thesis-t132, category 2 (``hitch profile show``): lift -0.223..0.663 rad, tilt 0.58..0.73 m,
top 0.655..0.905 m, left 0.5..0.58 m, right 0.5..0.575 m; workspace x ±0.06 m, z -0.2163..0.3117 m.
"""

import json

import pytest

from bridge.cli.main import main
from bridge.service.schemas import RequestError, parse_request
from planner.errors import unit_hint
from planner.trajectory import TrajectoryPlanner

NEUTRAL = {"--lift": "0.22", "--tilt": "0.63", "--top": "0.7425", "--left": "0.5388", "--right": "0.5388"}


def _fk(**override: str) -> list[str]:
    flags = dict(NEUTRAL)
    flags.update({f"--{k}": v for k, v in override.items()})
    return ["fk", *(x for kv in flags.items() for x in kv)]


def _err_line(capsys) -> str:
    out = capsys.readouterr()
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hitch: error:"), out.err
    assert "Traceback" not in out.err and "nan" not in lines[0].lower()
    return lines[0]


# ---------------------------------------------------------------------------------------- fk
def test_fk_refuses_a_lift_angle_off_its_range_naming_the_flag_not_the_closure(capsys):
    assert main(_fk(lift="300")) == 2
    line = _err_line(capsys)
    assert "--lift = 300 rad" in line and "range -0.223..0.663 rad" in line
    assert "closure" not in line and "cannot reach" not in line
    assert main(_fk(lift="3.0")) == 2  # it used to report a closure error of 0.00173 m
    line = _err_line(capsys)
    assert "--lift = 3 rad" in line and "-0.223..0.663 rad" in line and "closure" not in line
    assert "did you mean degrees? 3 deg = 0.0523599 rad" in line  # the service's hint for an angle


def test_fk_reports_every_actuator_off_its_stroke_with_the_mm_hint(capsys):
    assert main(_fk(tilt="630", top="742.5", left="5")) == 2
    line = _err_line(capsys)
    assert "--tilt = 630 m" in line and "0.58..0.73 m" in line and "did you mean mm? 630 mm = 0.63 m" in line
    assert "--top = 742.5 m" in line and "0.655..0.905 m" in line and "742.5 mm = 0.7425 m" in line
    assert "--left = 5 m" in line and "0.5..0.58 m" in line
    assert "5 mm" not in line.split("--left", 1)[1]  # 0.005 m is not within the stroke: no hint
    assert "--right" not in line and "--lift" not in line


def test_fk_at_the_stroke_ends_still_runs(capsys, model):
    for q in (model.lower, model.upper):
        argv = ["fk", *(x for n, v in zip(NEUTRAL, q, strict=True) for x in (n, repr(float(v)))), "--json"]
        code = main(argv)
        out = capsys.readouterr()
        # an end of a stroke is accepted by the range check; the mechanism may still refuse a combination
        assert code == 0 or "outside" not in out.err, out.err
        if code == 0:
            assert set(json.loads(out.out)["pose"]) == {"x", "y", "z", "roll", "pitch", "yaw"}


# ---------------------------------------------------------------------------------------- stability
def test_stability_refuses_a_pose_off_the_workspace_with_the_range_and_the_mm_hint(capsys):
    assert main(["stability", "--pose", "z=300"]) == 2
    line = _err_line(capsys)
    assert "--pose" in line and "pose.z = 300 m is above the workspace" in line
    assert "z from -0.2163 to 0.3117 m" in line and "did you mean mm? 300 mm = 0.3 m" in line
    assert "closure" not in line and "cannot reach" not in line


def test_stability_reports_every_dof_off_the_workspace(capsys):
    assert main(["stability", "--pose", "x=-50,z=0.1,roll=3"]) == 2
    line = _err_line(capsys)
    assert "pose.x = -50 m is right of the workspace" in line and "-50 mm = -0.05 m" in line
    assert "pose.roll = 3 rad is above the workspace" in line and "did you mean degrees?" in line
    assert "pose.z" not in line


def test_stability_inside_the_workspace_still_runs(capsys):
    assert main(["stability", "--pose", "z=0.1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["pose"]["z"] == pytest.approx(0.1)


def test_stability_refuses_an_implement_of_another_category(capsys):
    """An engineer's report: `--category 3 --implement cat2-power-harrow-1500` was evaluated and said ok."""
    assert main(["stability", "--category", "3", "--implement", "cat2-power-harrow-1500"]) == 2
    assert "is an ISO 730 category 2 implement; the hitch is set up for category 3" in capsys.readouterr().err


def test_stability_exits_1_when_the_verdict_is_not_ok(capsys):
    """An engineer's report: `NOT OK` (and "ok": false) came with exit 0, so a script could not use it."""
    argv = ["stability", "--pose", "z=0.3", "--slope-roll", "0.7", "--implement", "cat2-power-harrow-1500"]
    assert main([*argv, "--json"]) == 1
    assert json.loads(capsys.readouterr().out)["ok"] is False
    assert main(argv) == 1 and "NOT OK" in capsys.readouterr().out


def test_stability_states_the_ballast_rule_as_a_share_of_the_empty_tractors_weight(capsys):
    """A new user's report: "20 % of the weight on the front axle" beside "front share 16.8 %" and 0 kg of
    ballast read as a contradiction; the rule (docs/api.md) is front axle load >= 20 % of the empty tractor."""
    argv = ["stability", "--pose", "z=0.3", "--slope-roll", "0.17", "--implement", "cat2-power-harrow-1500"]
    assert main(argv) == 0
    out = " ".join(capsys.readouterr().out.split())  # rich may wrap the long line
    assert "front share 16.8 %" in out
    assert "20 % of the empty tractor's weight" in out
    assert "of the weight on the front axle" not in out


# ---------------------------------------------------------------------------------------- plan
def test_plan_reports_every_goal_dof_off_the_workspace_with_the_mm_hint(capsys):
    assert main(["plan", "--to", "x=50,z=300"]) == 2
    line = _err_line(capsys)
    assert "--to" in line
    assert "goal.x = 50 m is left of the workspace (x from -0.06 to 0.06 m, workspace:x:max)" in line
    assert "did you mean mm? 50 mm = 0.05 m" in line
    assert "goal.z = 300 m is above the workspace (z from -0.2163 to 0.3117 m, workspace:z:max)" in line
    assert "did you mean mm? 300 mm = 0.3 m" in line


def test_plan_names_the_start_and_the_goal_at_once(capsys):
    assert main(["plan", "--from", "x=50", "--to", "z=300"]) == 2
    line = _err_line(capsys)
    assert "--from" in line and "from.x = 50 m" in line and "50 mm = 0.05 m" in line
    assert "--to" in line and "goal.z = 300 m" in line and "300 mm = 0.3 m" in line


def test_plan_words_the_refusal_as_the_service_goto_does(capsys, model):
    ws = TrajectoryPlanner(model).workspace
    with pytest.raises(RequestError) as info:
        parse_request("goto", json.dumps({"goal": {"x": 50, "z": 300}}), workspace=ws)
    service = str(info.value).split(": outside the workspace: ", 1)[1]
    assert main(["plan", "--to", "x=50,z=300"]) == 2
    assert _err_line(capsys) == f"hitch: error: --to: outside the workspace: {service}"


# ---------------------------------------------------------------------------------------- helper
@pytest.mark.parametrize(
    "value, lo, hi, unit, hint",
    [
        (630.0, 0.58, 0.73, "m", "; did you mean mm? 630 mm = 0.63 m"),
        (5.0, 0.5, 0.58, "m", ""),  # 0.005 m is off the range too
        (3.0, -0.223, 0.663, "rad", "; did you mean degrees? 3 deg = 0.0523599 rad; or mrad? 3 mrad = 0.003 rad"),
        # 300 deg is no angle of the range; 300 mrad is (a pose plan-poses printed in mrad, copied as rad)
        (300.0, -0.223, 0.663, "rad", "; did you mean mrad? 300 mrad = 0.3 rad"),
        (1000.0, -0.223, 0.663, "rad", ""),  # neither
        (0.6, 0.58, 0.73, "m", ""),  # inside: nothing to hint
        (630.0, 0.58, 0.73, "N", ""),  # no hint for other units
    ],
)
def test_unit_hint_is_the_services(value, lo, hi, unit, hint):
    assert unit_hint(value, lo, hi, unit) == hint
