"""Error reporting of ``hitch`` (bridge.cli.main): a HitchError is the user's, anything else is a bug.

Truth: the rule itself — every error the project raises on purpose derives from
:class:`planner.errors.HitchError` and is printed as one line ``hitch: error: …`` with exit
status 2; any other exception propagates out of :func:`main` with its traceback.
"""

import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest

from bridge.cli import model as cli_model
from bridge.cli.errors import CLIError
from bridge.cli.main import main
from bridge.cli.service import _read_script
from planner.errors import HitchError, HitchInputError


def _raising(exc: BaseException):
    def handler(args) -> int:
        raise exc

    return handler


@pytest.mark.parametrize(
    "exc",
    [
        RuntimeError("a bug"),
        KeyError("missing"),
        ValueError("a bare ValueError is a bug too"),
        TypeError("wrong type"),
        AttributeError("no such attribute"),
    ],
    ids=lambda e: type(e).__name__,
)
def test_a_non_hitch_error_propagates_with_its_traceback(monkeypatch, capsys, exc):
    monkeypatch.setattr(cli_model, "_cmd_demo", _raising(exc))
    with pytest.raises(type(exc)) as info:
        main(["demo"])
    assert info.value is exc
    assert "hitch: error" not in capsys.readouterr().err


@pytest.mark.parametrize(
    "exc, line",
    [
        (HitchError("the hitch refused"), "hitch: error: the hitch refused"),
        (HitchInputError("z = 9 is outside ±10 m"), "hitch: error: z = 9 is outside ±10 m"),
        (CLIError("maneuver file x.yaml does not exist"), "hitch: error: maneuver file x.yaml does not exist"),
        (HitchError("first line\nsecond line"), "hitch: error: first line; second line"),
    ],
)
def test_a_hitch_error_is_one_line_on_stderr_and_exit_2(monkeypatch, capsys, exc, line):
    monkeypatch.setattr(cli_model, "_cmd_demo", _raising(exc))
    assert main(["demo"]) == 2
    out = capsys.readouterr()
    assert out.out == ""
    assert out.err.splitlines() == [line]


def test_a_subclass_defined_elsewhere_is_reported_as_well(monkeypatch, capsys):
    class SomeModuleError(HitchInputError):
        pass

    monkeypatch.setattr(cli_model, "_cmd_demo", _raising(SomeModuleError("bad value")))
    assert main(["demo"]) == 2
    assert capsys.readouterr().err == "hitch: error: bad value\n"


def test_cli_error_is_a_hitch_input_error():
    assert issubclass(CLIError, HitchError)
    assert issubclass(CLIError, ValueError)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["fk", "--lift", "0.2"], "hitch fk: the following arguments are required: --tilt"),
        (["nope"], "hitch: error: argument command: invalid choice: 'nope'"),
        (["ik", "--x", "0", "--z", "0", "--roll", "0", "--pitch", "0", "--method", "magic"], "invalid choice: 'magic'"),
        (["plan", "--to", "q=1"], "unknown pose field 'q'"),
        (["arm", "fk", "--joints=1,x"], "--joints must be comma-separated numbers"),
        (["profile", "frobnicate"], "hitch profile: argument profile_command: invalid choice"),
        (["maneuver", "run"], "hitch maneuver run: the following arguments are required: name"),
        # a negative seed was a numpy traceback ("expected non-negative integer") in these two
        (["calibrate", "plan-poses", "--seed", "-1", "--n", "4"], "--seed must be a whole number >= 0, got -1"),
        (
            ["calibrate", "measure-twin", "--seed", "-1", "--n", "4", "--out", "m.csv"],
            "--seed must be a whole number >= 0, got -1",
        ),
        (["sim", "perturb", "--seed", "-1", "--tape", "--out", "t.toml"], "--seed must be a whole number >= 0"),
    ],
)
def test_argparse_errors_reach_the_user_as_cli_errors(capsys, argv, message):
    assert main(argv) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hitch: error: ") and message in lines[0]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["presets"], "argument command: invalid choice: 'presets'"),
        ([], "the following arguments are required: command"),
        (["--no-such-flag"], "the following arguments are required: command"),
    ],
    ids=["unknown-command", "no-command", "unknown-flag"],
)
def test_a_top_level_argument_error_names_hitch_once(capsys, argv, message):
    assert main(argv) == 2
    out = capsys.readouterr()
    assert out.out == ""
    (line,) = out.err.splitlines()
    assert line.startswith(f"hitch: error: {message}"), line
    assert line.count("hitch:") == 1, line


def test_a_subcommand_argument_error_names_the_subcommand(capsys):
    assert main(["fk", "--lift", "0.2"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("hitch: error: hitch fk: the following arguments are required: --tilt"), line


def test_version_prints_the_installed_distribution_version_and_exits_0(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    out = capsys.readouterr()
    assert out.out == f"hitch {metadata.version('hitch-planner')}\n"
    assert out.err == ""


def test_version_of_the_console_script():
    r = subprocess.run(
        [str(Path(sys.executable).with_name("hitch")), "--version"], capture_output=True, text=True, timeout=60
    )
    assert (r.returncode, r.stdout, r.stderr) == (0, f"hitch {metadata.version('hitch-planner')}\n", "")


def test_the_cli_own_validation_raises_cli_error(tmp_path):
    with pytest.raises(CLIError, match="does not exist"):
        _read_script(str(tmp_path / "missing.yaml"))
    with pytest.raises(CLIError, match="is not a regular file"):  # a new user's report: a folder "does not exist"
        _read_script(str(tmp_path))
    script = tmp_path / "m.yaml"
    script.write_text("steps: []\n", encoding="utf-8")
    assert _read_script(str(script)) == "steps: []\n"


def test_a_profile_that_fails_pydantic_validation_is_a_user_error(tmp_path, capsys):
    from importlib import resources

    text = (resources.files("planner") / "profiles" / "thesis-t132.toml").read_text(encoding="utf-8")
    bad = tmp_path / "bad.toml"
    bad.write_text(text + "\nnot_a_field = 1\n", encoding="utf-8")
    assert main(["profile", "show", "--profile", str(bad)]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hitch: error: ") and "not_a_field" in lines[0]


def test_a_service_config_that_fails_pydantic_validation_is_a_user_error(capsys):
    # load_service_config validates with pydantic before anything is started
    assert main(["serve", "--control-rate", "5"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hitch: error: invalid service config (flags): ")
    assert "control_rate" in lines[0]


def test_a_service_that_does_not_answer_a_secured_client_names_the_credentials_too():
    """A fleet integrator's report: a wrong password read "no hitch service … start one with hitch serve"."""
    import argparse

    from bridge.cli.service import _service_down

    plain = str(_service_down(argparse.Namespace(connect=None, prefix="hitch", security=None), Exception("no reply")))
    assert "start one with `hitch serve`" in plain
    # a secured service answers no client without credentials: said too (a security engineer's report)
    assert plain.endswith("answers only clients with credentials: give them with --security FILE"), plain
    args = argparse.Namespace(connect=["tcp/127.0.0.1:1"], prefix="fleet/t07/hitch", security="alice.json5")
    secured = str(_service_down(args, Exception("no reply")))
    assert "with --security alice.json5: the user and password may be refused there" in secured


def test_a_client_that_reaches_nothing_says_so_without_zenoh_s_source_location(capsys):
    """A fleet trial: "Unable to connect to any of [...]!  at /root/.cargo/git/checkouts/…/orchestrator.rs:447."
    and nothing about what to check."""
    from bench._common import free_port

    port = free_port()  # nothing listens there
    assert main(["state", "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "2"]) == 2
    err = capsys.readouterr().err
    assert f"cannot open a Zenoh session to tcp/127.0.0.1:{port}" in err, err
    assert ".rs:" not in err and ".cargo" not in err and "is the router or service running there?" in err, err
