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
