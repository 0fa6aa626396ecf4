"""CLI: fk, profile show and errors, run as a user would (real subprocess of the console script)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

HITCH = [str(Path(sys.executable).with_name("hitch"))]


def run(*args):
    return subprocess.run(HITCH + list(args), capture_output=True, text=True, timeout=120)


def test_fk_json_matches_the_model(model):
    q = model.neutral
    r = run(
        "fk",
        "--lift",
        str(q[0]),
        "--tilt",
        str(q[1]),
        "--top",
        str(q[2]),
        "--left",
        str(q[3]),
        "--right",
        str(q[4]),
        "--json",
    )
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert set(d["pose"]) == {"x", "y", "z", "roll", "pitch", "yaw"}
    assert d["pose"]["z"] == pytest.approx(model.neutral_pose.z, abs=1e-12)
    assert {"L", "R", "T", "U", "H", "S_l", "S_r", "C_l", "C_r"} <= set(d["points"])
    assert len(d["points"]["U"]) == 3
    assert d["warnings"] == []  # the neutral lengths fit the implement


def test_fk_of_lengths_no_implement_fits_warns():
    """An engineer's report: 51 mm of span mismatch and a top-link yaw beyond its limit came back without a word."""
    r = run("fk", "--lift", "0.22", "--tilt", "0.63", "--top", "0.74", "--left", "0.5", "--right", "0.575")
    assert r.returncode == 0, r.stderr
    assert "warning: not a pose the implement can take: the lower-link balls are 0.9164 m apart" in r.stdout
    assert "(+51.4 mm)" in r.stdout and "warning: beyond the hard limits: top_link_yaw_min" in r.stdout


def test_profile_show_json():
    r = run("profile", "show", "--category", "3", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["category"] == "3" and d["span"] == pytest.approx(1.005)
    assert set(d["workspace"]) == {"x", "z", "roll", "pitch"}


@pytest.mark.parametrize(
    "args, message",
    [
        (["fk", "--lift", "0.2", "--tilt", "5", "--top", "0.75", "--left", "0.54", "--right", "0.54"], "tilt cylinder"),
        (
            ["fk", "--lift", "nan", "--tilt", "0.6", "--top", "0.75", "--left", "0.54", "--right", "0.54"],
            "--lift must be finite",
        ),
        (["fk", "--lift", "0.2"], "required"),
        (["profile", "show", "--category", "9"], "category '9' is not in profile"),
        (["profile", "show", "--profile", "nope"], "profile 'nope' not found"),
        # a new user's report: 'rate must lie within 1..200 Hz, got nan' did not name the option
        (["plan", "--to", "z=0.1", "--rate", "nan"], "--rate must be finite"),
        (["plan", "--to", "z=0.1", "--rate", "500"], "--rate must lie in [1, 200] Hz"),
        (["sim", "move", "--to", "z=0.1", "--rate", "0"], "--rate must lie in [1, 200] Hz"),
        # a new user's report: a bad --plot ended a whole simulation with a traceback
        (["sim", "move", "--to", "z=0.1", "--plot", "/nonexistent/dir/m.png"], "folder '/nonexistent/dir' does not"),
        (["sim", "move", "--to", "z=0.1", "--plot", "m.txt"], "the file name must end in one of"),
        (["plan", "--to", "z=0.1", "--plot", "plan.doc"], ".png"),
        (["sim", "track", "levelling", "--plot", "/nonexistent/t.png"], "--plot"),
    ],
)
def test_errors_exit_non_zero_with_one_line(args, message):
    r = run(*args)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hitch: error:") and message in lines[0]


def test_piped_output_keeps_each_record_on_one_line():
    """Into a pipe rich took 80 columns and split records from their units ('yaw=' alone on a line of
    `hitch ik`, 'plan 2.28 \\ns)' in `hitch sim move`): every pose line now holds all six values."""
    r = run("ik", "--x", "0.02", "--z", "0.1", "--roll", "0", "--pitch", "0")
    assert r.returncode == 0, r.stderr
    pose = [ln for ln in r.stdout.splitlines() if ln.startswith("pose:")]
    assert len(pose) == 1 and all(f"{k}=" in pose[0] for k in ("x", "y", "z", "roll", "pitch", "yaw")), r.stdout
    assert not any(ln.lstrip().startswith("yaw=") for ln in r.stdout.splitlines()), r.stdout
    r = run("fk", "--lift", "0.2", "--tilt", "0.63", "--top", "0.74", "--left", "0.54", "--right", "0.54")
    assert r.returncode == 0, r.stderr
    assert not any(ln.lstrip().startswith("yaw=") for ln in r.stdout.splitlines()), r.stdout


@pytest.mark.parametrize(
    ("lo_open", "hi_open", "inside", "outside", "allowed"),
    [
        (True, False, ["0.5", "1"], ["0", "1.0001"], "(0, 1]"),
        (False, False, ["0", "1"], ["-0.0001", "1.0001"], "[0, 1]"),
        (False, True, ["0", "0.999"], ["1", "-0.0001"], "[0, 1)"),
        (True, True, ["0.5"], ["0", "1"], "(0, 1)"),
    ],
)
def test_bounded_float_keeps_each_end_open_or_closed_and_names_the_range(lo_open, hi_open, inside, outside, allowed):
    import argparse

    from bridge.cli.model import bounded_float

    parse = bounded_float("--p", 0.0, 1.0, lo_open=lo_open, hi_open=hi_open)
    for text in inside:
        assert parse(text) == float(text)
    for text in [*outside, "nan", "inf"]:
        with pytest.raises(argparse.ArgumentTypeError, match="--p") as err:
            parse(text)
        if text not in ("nan", "inf"):
            assert f"--p must lie in {allowed}, got {text}" == str(err.value)


def test_sim_move_frame_loss_is_a_probability_below_one(capsys):
    from bridge.cli.main import main

    for text in ("1", "-0.1"):
        assert main(["sim", "move", "--frame-loss", text]) == 2
        err = capsys.readouterr().err
        assert f"--frame-loss must lie in [0, 1), got {text}" in err and "Traceback" not in err


def test_profile_show_refuses_a_restricted_box_serve_refuses(tmp_path):
    """`profile show` exited 0 with "warnings": [] for a box whose corners the mechanism cannot reach; serve then
    failed "control core could not start: PlanError: workspace.restricted.2 … not all reachable"."""
    from importlib import resources

    text = (resources.files("planner") / "profiles" / "thesis-t132.toml").read_text()
    good = "[workspace.restricted.2]\nx = [-0.060000, 0.060000]"
    assert good in text
    bad = tmp_path / "wide.toml"
    bad.write_text(text.replace(good, "[workspace.restricted.2]\nx = [-0.300000, 0.300000]"))
    for extra in ([], ["--json"]):
        r = run("profile", "show", "--profile", str(bad), "--category", "2", *extra)
        assert r.returncode == 2, r.stdout
        assert "workspace.restricted.2" in r.stderr and "not all reachable" in r.stderr
        assert "hitch profile fit-workspace" in r.stderr
        assert r.stdout == ""
    # another category's box (reachable) still shows; the shipped profile's boxes all pass
    assert run("profile", "show", "--profile", str(bad), "--category", "3", "--json").returncode == 0
    r = run("profile", "show", "--category", "2", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["warnings"] == []
