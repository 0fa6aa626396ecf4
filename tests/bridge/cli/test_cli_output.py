"""What ``hitch`` prints: no traceback for a move of length zero, no NaN in text or JSON, units on poses,
option errors naming the option and its range.

Truths: a plan whose goal is its start has duration 0 and a lower bound 0 (its ratio is undefined: the
old CLI divided by zero); strict JSON (RFC 8259) has no NaN/Infinity token — Python's ``json.loads`` with
a ``parse_constant`` that refuses them is the strict reader; the service's own speed-scale range
(``MIN_SPEED_SCALE``) is what the offline commands must accept too.
"""

from __future__ import annotations

import json
import math

import pytest

from bridge.cli.main import main
from bridge.service.maneuvers.language import MIN_SPEED_SCALE
from bridge.service.wire import to_json_text


def _strict(text: str):
    def refuse(token: str):
        raise ValueError(f"non-standard JSON token {token}")

    return json.loads(text, parse_constant=refuse)


def test_to_json_text_writes_null_for_non_finite_numbers():
    obj = {"a": math.nan, "b": [1.0, math.inf, -math.inf], "c": {"d": 2.5}, "e": "nan"}
    assert _strict(to_json_text(obj)) == {"a": None, "b": [1.0, None, None], "c": {"d": 2.5}, "e": "nan"}
    assert _strict(to_json_text(obj, indent=1)) == _strict(to_json_text(obj))
    with pytest.raises(ValueError, match="NaN"):
        _strict(json.dumps(obj))  # what the CLI wrote before


@pytest.mark.parametrize("args", [["--to", "x=0"], ["--to", "z=0.1", "--from", "z=0.1"]])
def test_plan_whose_goal_is_its_start_prints_a_move_of_length_zero(capsys, args):
    assert main(["plan", *args]) == 0  # the old CLI raised ZeroDivisionError here
    out = capsys.readouterr().out
    assert "duration 0.000 s" in out and "the start is the goal" in out
    end = next(line for line in out.splitlines() if line.startswith("end pose:"))
    assert end.count(" m") == 3 and end.count(" rad") == 3  # x, y, z in m; roll, pitch, yaw in rad


def test_sim_track_without_a_judged_sample_says_so_in_text_and_writes_strict_json(capsys, tmp_path):
    path = tmp_path / "t.json"
    assert main(["sim", "track", "levelling", "--duration", "6", "--json", str(path)]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out.lower() and "no sample to judge" in out
    data = _strict(path.read_text())  # the old file held bare NaN tokens
    assert data["scenario"] == "levelling"


def test_sim_field_without_a_heavy_patch_says_so_and_writes_strict_json(capsys, tmp_path):
    path = tmp_path / "f.json"
    args = ["sim", "field", "chisel", "--mode", "draft", "--draft-setpoint", "20000", "--duration", "4"]
    assert main([*args, "--json", str(path)]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out.lower() and "heavy patches n/a" in out
    figures = _strict(path.read_text())["figures"]
    assert figures["heavy_samples"] == 0 and figures["slip_max_heavy"] is None


@pytest.mark.parametrize("command", [["sim", "track", "flat"], ["sim", "field", "chisel"]])
def test_sim_track_and_field_json_without_a_file_prints_only_strict_json_as_every_other_json_flag(capsys, command):
    assert main([*command, "--duration", "7", "--json"]) == 0
    out = capsys.readouterr().out
    data = _strict(out)  # one JSON document and nothing else (the old --json took the next word as its FILE)
    assert data.get("scenario", data.get("field")) == command[2]


@pytest.mark.parametrize("command", [["sim", "track", "flat"], ["sim", "field", "chisel"]])
def test_sim_track_and_field_json_file_is_checked_before_the_run(capsys, tmp_path, command):
    for bad, why in ((tmp_path / "no" / "s.json", "does not exist"), (tmp_path, "is a folder")):
        assert main([*command, "--duration", "7", "--json", str(bad)]) == 2
        err = capsys.readouterr().err
        assert "--json" in err and why in err and "Traceback" not in err  # was a FileNotFoundError after the run


@pytest.mark.parametrize(
    "args, option, allowed",
    [
        (["plan", "--to", "z=0.1", "--speed-scale", "0.001"], "--speed-scale", f"[{MIN_SPEED_SCALE:g}, 1]"),
        (["sim", "move", "--to", "z=0.1", "--speed-scale", "0"], "--speed-scale", f"[{MIN_SPEED_SCALE:g}, 1]"),
        (["sim", "move", "--to", "z=0.1", "--max-time", "-1"], "--max-time", "[0.1, 600] s"),
        (["sim", "move", "--to", "z=0.1", "--band-position", "-1"], "--band-position", "(0, 10] m"),
        (["sim", "move", "--to", "z=0.1", "--band-angle", "nan"], "--band-angle", ""),
        (["sim", "move", "--to", "z=0.1", "--frame-loss", "1.5"], "--frame-loss", "[0, 1)"),
        (["sim", "fault", "--loss", "1.5"], "--loss", "[0, 1]"),  # the old CLI: "loss must be …" from the service
        (["sim", "fault", "--delay-ms", "-1"], "--delay-ms", "ms"),
        (["sim", "fault", "--timeout", "0"], "--timeout", "(0, 600] s"),  # sim fault's own copy took 0
        (["stability", "--slope-roll", "2"], "--slope-roll", "[-1.5707, 1.5707] rad"),  # was "slope_roll must"
    ],
)
def test_option_errors_name_the_option_and_its_range(capsys, args, option, allowed):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"{option} must" in err and allowed in err, err


@pytest.mark.parametrize(
    "args, what",
    [
        (["profile", "show", "--profile", "{dir}/p.toml"], "profile file"),
        (["maneuver", "validate", "{dir}/m.yaml"], "maneuver file"),  # before any connection is tried
        (["maneuver", "save", "x1", "{dir}/m.yaml"], "maneuver file"),
        (["sim", "track", "{dir}/s.toml"], "scenario"),
    ],
)
def test_a_file_that_is_not_utf8_is_one_error_line_naming_file_and_byte(capsys, tmp_path, args, what):
    """The old CLI ended these with a UnicodeDecodeError traceback (exit 1)."""
    for name, text in (("p.toml", b'name = "x"\n# caf\xe9\n'), ("m.yaml", b"steps:\n  - goto: {z: 0.1\xff}\n")):
        (tmp_path / name).write_bytes(text)
    (tmp_path / "s.toml").write_bytes(b'job = "levelling"\n# \xff\n')
    assert main([a.format(dir=tmp_path) for a in args]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"hitch: error: {what}") and "not UTF-8 text (byte " in err and "line 2" in err, err


def test_a_profile_value_of_the_wrong_type_is_refused_naming_the_field(capsys, tmp_path):
    """The old loader read ``true`` as 1.0 m and ``"0.960"`` as 0.96 m (pydantic's lax mode)."""
    import importlib.resources

    text = (importlib.resources.files("planner.profiles") / "thesis-t132.toml").read_text(encoding="utf-8")
    line = next(x for x in text.splitlines() if x.startswith("lower_link_length"))
    for bad in ("true", '"0.960"'):
        p = tmp_path / "p.toml"
        p.write_text(text.replace(line, f"lower_link_length = {bad}"), encoding="utf-8")
        assert main(["profile", "show", "--profile", str(p)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"hitch: error: invalid profile {p}: geometry.lower_link_length = "), err
        assert "valid number" in err and "(allowed: > 0 and <= 3 m)" in err and ":;" not in err, err


def test_the_mode_argument_is_named_as_the_usage_shows_it(capsys):
    """The old error said 'argument set: invalid choice' ('set' appears nowhere in the usage line)."""
    assert main(["mode", "bogus"]) == 2
    err = capsys.readouterr().err
    assert "argument MODE: invalid choice: 'bogus'" in err, err


def test_sim_move_of_length_zero_has_no_overshoot_share(capsys):
    """A share of a move inside the settling band means nothing: the old CLI printed 'overshoot 110.21 %'."""
    assert main(["sim", "move", "--from", "x=0", "--to", "x=0"]) == 0
    out = capsys.readouterr().out
    assert out.count("overshoot n/a (the move lies within the settling band)") == 2, out


def test_sim_move_refuses_an_option_its_reference_does_not_use(capsys):
    """--no-feedforward was accepted without effect for a step reference."""
    assert main(["sim", "move", "--to", "z=0.3", "--reference", "step", "--no-feedforward"]) == 2
    assert "--no-feedforward applies to --reference trajectory only" in capsys.readouterr().err


@pytest.mark.parametrize("command, least", [(["sim", "track", "levelling"], 5.5), (["sim", "field", "chisel"], 3.5)])
@pytest.mark.parametrize("duration", ["0.5", "1", "3"])
def test_a_run_too_short_names_the_one_range_a_duration_has(capsys, command, least, duration):
    """The old loop said 'must be a number in [1, 3600]' for 0.5 and 'must exceed … 5.5 s' for 1; then it named
    the loop's field duration_s, not the flag, and nan got another range (a new user's report)."""
    from bridge.cli.sim import _FIELD_SETTLE_S, _TRACK_SETTLE_S
    from bridge.service.field_loop import FieldLoopSettings
    from bridge.service.track_loop import LoopSettings

    for settings, bound in ((LoopSettings(), _TRACK_SETTLE_S), (FieldLoopSettings(), _FIELD_SETTLE_S)):
        assert settings.warmup_s + settings.settle_s == bound  # the flag's bound is the loop's
    for value, words in ((duration, f"must lie in ({least:g}, 3600] s, got {duration}"), ("nan", "must be finite")):
        assert main([*command, "--duration", value]) == 2
        err = capsys.readouterr().err
        assert f"argument --duration: --duration {words}" in err and "duration_s" not in err, err


@pytest.mark.parametrize("command", [["sim", "track"], ["sim", "field"]])
def test_a_name_right_after_json_is_refused_as_its_file_naming_the_cure(capsys, command):
    """A new user's report: `hitch sim track --json levelling-inside` said "the following arguments are required:
    scenario" (--json took the scenario's name as its FILE)."""
    assert main([*command, "--json", "levelling-inside"]) == 2
    err = capsys.readouterr().err
    assert "argument --json: FILE 'levelling-inside' must end in .json" in err and "give it before --json" in err


def test_control_limited_is_printed_in_words_with_its_code():
    """A new user's report: `control limited: end_stop:lift: speed: end_stop:lift would be 0.8086 (threshold 1)
    at t = 0.00 s` named the limit twice and gave a speed factor without saying so."""
    from bridge.cli.output import limited_text
    from bridge.cli.service import _state_line

    lim = {"end_stop:lift": "speed: end_stop:lift would be 0.8086 (threshold 1) at t = 0.00 s", "z": "workspace:z:max"}
    text = limited_text(lim)
    end_stop = "lift arm slowing before its stroke end: slowed to 81 % (end_stop:lift)"  # the factor 0.8086 in %
    assert text == f"{end_stop}, height limit reached (top) (z)"
    assert f"control limited: {end_stop}" in _state_line({"limited": lim})


def test_the_state_line_says_what_runs_a_maneuver_waiting_a_track_session_work_control():
    """A field trial: `hitch state` said "#2012 auto at rest motion 13 …" while a maneuver waited for a line
    16.8 m ahead and work control ran; now the line names them."""
    from bridge.cli.service import _state_line

    state = {
        "seq": 2012,
        "mode": "auto",
        "moving": False,
        "motion_id": 13,
        "maneuver": {"name": "headland", "step": 2, "kind": "wait_for", "paused": False, "distance_left": 16.84},
        "work": {"running": True, "mode": "draft", "active": "position", "fallback": "no draft reading"},
    }
    line = _state_line(state)
    assert "maneuver headland step 3 (index 2) wait_for 16.8 m left" in line, line
    assert "work position (fallback: no draft reading)" in line, line
    state = {"track": {"session": 7, "frame": "level", "dof": ["roll"], "stale": True}, "work": {"running": False}}
    line = _state_line(state)
    assert "track session 7 (level, roll) stale" in line and "work" not in line, line
