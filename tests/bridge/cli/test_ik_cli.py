"""``hitch ik --method dls|hybrid|geometric`` prints a baseline's broken limits like the QP's "limited" (a new
user's trial: "status: ok" with both sway limiters beyond their strokes)."""

import pytest

from bridge.cli import main

ARGS = ["ik", "--x", "0.5", "--z", "0.2", "--roll", "0", "--pitch", "0"]


@pytest.mark.parametrize("method", ["dls", "hybrid", "geometric"])
def test_a_baseline_beyond_the_strokes_prints_limited(method, capsys):
    assert main([*ARGS, "--method", method]) == 0  # as the qp method's "limited"
    out = capsys.readouterr().out
    assert "status: ok" not in out
    assert f"status: limited — {method}: the method enforces no limit and breaks stroke:left:min" in out
    assert "limits broken: stroke:left:min, stroke:right:max" in out


def test_the_qp_method_still_prints_its_active_limits(capsys):
    assert main(ARGS) == 0
    out = capsys.readouterr().out
    assert "status: limited" in out and "active limits: " in out and "stroke:right:max" in out


def test_ik_and_demo_print_every_number_with_its_unit_and_name_the_error(capsys):
    """A newcomer's trial: `hitch ik` printed actuators and pose without units and two residuals ("weighted
    residual 0.299", "residual 0.27") without saying which is which; `hitch demo` its neutral posture unitless."""
    main(["ik", "--x", "0.5", "--z", "0.2", "--roll", "0", "--pitch", "0"])
    out = capsys.readouterr().out
    assert "lift=0.38859 rad  tilt=0.68374 m" in out and "roll=-0.21264 rad" in out, out
    assert "pose - target: x -269.7 mm, z -7.1 mm, roll -212.6 mrad, pitch -7.4 mrad" in out, out
    assert ", residual" not in out, out
    assert main(["demo"]) == 0
    out = capsys.readouterr().out
    assert "neutral actuators: lift=0.2200 rad  tilt=0.6300 m" in out and "z=+0.1137 m" in out, out
