"""``arm fk`` / ``arm ik`` (bridge.cli.arm): the pure command functions and the parser plug-in.

Truth: the worked example of the arm source (printed numbers in mm and degrees, converted to
SI here), the CAD frames of its figure 3.6, and the command functions themselves for the
parser round trip.
"""

import argparse
import json
import math

import numpy as np
import pytest

from bridge.cli.arm import add_arm_parser, arm_fk_command, arm_ik_command
from planner.arm.analytic import NoAdmissibleSolutionError, UnreachableTargetError

MM, DEG = 1e-3, math.pi / 180
P_TARGET = [0.100, 0.050, 0.120]  # (100, 50, 120) mm
R06_ROWS = [-0.1219, -0.9917, 0.0406, -0.1241, -0.0253, -0.9919, 0.9847, -0.1260, -0.1200]
FIRST_DEG = [35.1493, -12.4968, 74.2324, 63.4518, 111.1249, -147.4508]  # verified first solution
CAD_TOOL_ORIGIN_MM = [99.999987887, 49.999179031, 119.999955725]  # figure 3.6
CAD_WRIST_ORIGIN_MM = [99.187937468, 69.838029370, 122.400078914]  # figure 3.6, y typo fixed


def parser():
    p = argparse.ArgumentParser(prog="hitch")
    add_arm_parser(p.add_subparsers(dest="command", required=True))
    return p


def test_fk_command_reproduces_the_cad_frames():
    out = arm_fk_command([x * DEG for x in FIRST_DEG])
    json.dumps(out)  # JSON-ready
    # 4-decimal angles move the tool by at most ~4e-4 mm (lever arms × 8.7e-7 rad).
    np.testing.assert_allclose(np.array(out["position"]) / MM, CAD_TOOL_ORIGIN_MM, atol=1e-6)
    np.testing.assert_allclose(np.array(out["wrist_centre"]) / MM, CAD_WRIST_ORIGIN_MM, atol=1e-6)
    np.testing.assert_allclose(np.array(out["rotation"])[:, 2], [0.040602521, -0.991942517, -0.120006159], atol=1e-8)
    assert out["within_limits"] and out["limit_violations"] == []
    assert list(out["origins"]) == [
        "base",
        "waist",
        "shoulder",
        "elbow",
        "forearm_roll",
        "wrist_bend",
        "flange_roll",
        "tool",
    ]
    assert out["origins"]["forearm_roll"] == out["wrist_centre"]


def test_fk_command_reports_limits_and_bad_input():
    out = arm_fk_command([4.0, 0, 0, 0, 0, 0])
    assert not out["within_limits"] and "waist = 4" in out["limit_violations"][0]
    with pytest.raises(ValueError, match="joints must have 6 joint values"):
        arm_fk_command([0.0, 0.0])


def test_ik_command_all_solutions_json_shape():
    out = arm_ik_command(P_TARGET, R06_ROWS, all_solutions=True)
    assert set(out) == {"solutions", "wrist_centre"}
    assert len(out["solutions"]) == 8
    for s in out["solutions"]:
        assert set(s) == {"joints", "fk_error"}
        assert len(s["joints"]) == 6 and all(-math.pi < q <= math.pi for q in s["joints"])
        assert s["fk_error"] <= 1e-9
    # Printed wrist centre (99.1880, 69.8380, 122.4000) mm; projecting the 4-decimal R06 onto
    # SO(3) moves it by at most d6 · √3 · 5e-5 = 1.7e-3 mm.
    np.testing.assert_allclose(np.array(out["wrist_centre"]) / MM, [99.1880, 69.8380, 122.4000], atol=1.8e-3)
    firsts = [s for s in out["solutions"] if abs(s["joints"][5] - FIRST_DEG[5] * DEG) < 1e-4]
    assert any(np.allclose(np.degrees(s["joints"]), FIRST_DEG, atol=0.005) for s in firsts)
    json.dumps(out)


def test_ik_command_default_picks_the_admissible_solution_nearest_the_reference():
    everything = arm_ik_command(P_TARGET, R06_ROWS, all_solutions=True)["solutions"]
    for ref in (np.zeros(6), np.array(FIRST_DEG) * DEG, np.array([-2.5, 2.5, 1.3, 0, 0, 0])):
        out = arm_ik_command(P_TARGET, R06_ROWS, reference=ref)
        assert len(out["solutions"]) == 1
        nearest = min(everything, key=lambda s: float(np.sum((np.array(s["joints"]) - ref) ** 2)))
        np.testing.assert_allclose(out["solutions"][0]["joints"], nearest["joints"], atol=1e-12)


def test_ik_command_errors():
    with pytest.raises(UnreachableTargetError, match="too far"):
        arm_ik_command([1.0, 0.0, 0.0], np.eye(3).ravel())
    with pytest.raises(ValueError, match="rotation must be a 3x3 matrix"):
        arm_ik_command(P_TARGET, [1.0, 0.0, 0.0])


def test_ik_command_with_a_profile_whose_limits_exclude_every_solution(tmp_path):
    from importlib import resources

    text = (resources.files("planner") / "profiles" / "arms" / "arm-source-example.toml").read_text(encoding="utf-8")
    # Shoulder limited to [-0.1, 0.1] rad: no solution of the worked example has |q2| that small.
    text = text.replace(
        'name = "shoulder"           # source theta2, upper-arm elevation\n'
        'type = "revolute"\n'
        "a = 0.100                   # a2 = 100 mm\n"
        "alpha = 0.0\nd = 0.0\ntheta = 0.0\nlower = -3.141592653589793\nupper = 3.141592653589793",
        'name = "shoulder"\ntype = "revolute"\na = 0.100\nalpha = 0.0\nd = 0.0\ntheta = 0.0\nlower = -0.1\nupper = 0.1',
    )
    assert "lower = -0.1" in text
    path = tmp_path / "arm-tight.toml"
    path.write_text(text, encoding="utf-8")
    assert len(arm_ik_command(P_TARGET, R06_ROWS, True, path)["solutions"]) == 8
    with pytest.raises(NoAdmissibleSolutionError, match="shoulder = "):
        arm_ik_command(P_TARGET, R06_ROWS, False, path)


def test_parser_round_trip(capsys):
    rot = ",".join(str(x) for x in R06_ROWS)
    args = parser().parse_args(["arm", "ik", "--position=0.1,0.05,0.12", f"--rotation={rot}", "--all", "--json"])
    assert args.handler(args) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads(json.dumps(arm_ik_command(P_TARGET, R06_ROWS, all_solutions=True)))

    q = ",".join(str(x * DEG) for x in FIRST_DEG)
    args = parser().parse_args(["arm", "fk", f"--joints={q}", "--json"])
    assert args.handler(args) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(json.dumps(arm_fk_command([x * DEG for x in FIRST_DEG])))

    args = parser().parse_args(["arm", "ik", "--position=0.1,0.05,0.12", f"--rotation={rot}"])
    assert args.handler(args) == 0
    text = capsys.readouterr().out
    assert "wrist centre" in text and text.count("fk error") == 1
    args = parser().parse_args(["arm", "fk", f"--joints={q}"])
    assert args.handler(args) == 0
    assert "within joint limits" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["arm", "ik", "--position=0.1,0.05", "--rotation=1,0,0,0,1,0,0,0,1"],
            "--position needs 3 comma-separated values",
        ),
        (
            ["arm", "ik", "--position=0.1,0.05,x", "--rotation=1,0,0,0,1,0,0,0,1"],
            "--position must be comma-separated numbers",
        ),
        (
            ["arm", "ik", "--position=0.1,0.05,0.1", "--rotation=1,0,0,0,1,0,0,0,nan"],
            "--rotation values must be finite",
        ),
        (["arm", "fk"], "--joints"),
    ],
)
def test_parser_errors(argv, message, capsys):
    with pytest.raises(SystemExit):
        parser().parse_args(argv)
    assert message in capsys.readouterr().err


def test_ik_command_rotation_error_names_what_the_bound_is_on():
    """A new user's trial: "allowed: <= 0.001 with det > 0" did not say what must be <= 0.001."""
    from planner.arm.transforms import RotationMatrixError

    bound = r"allowed: <= 0\.001 for max\|RᵀR - I\| \(elementwise\), with det\(R\) > 0"
    with pytest.raises(RotationMatrixError, match=r"it has max\|RᵀR - I\| = 0\.21; " + bound):
        arm_ik_command(P_TARGET, [1, 0, 0, 0, 1, 0, 0, 0, 1.1])
    with pytest.raises(RotationMatrixError, match=r"it has det <= 0 \(a reflection or singular\); " + bound):
        arm_ik_command(P_TARGET, [1, 0, 0, 0, 1, 0, 0, 0, -1])
