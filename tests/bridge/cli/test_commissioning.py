"""``hitch accuracy-test`` and ``hitch calibrate sensors`` end to end (simulated time)."""

import json
import tomllib

import pytest

from bridge.cli import main
from planner.profiles.hitch import load_profile


@pytest.fixture(scope="module")
def truth_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("truth") / "truth.toml"
    assert main(["sim", "perturb", "--seed", "1", "--tape", "--out", str(path), "--json"]) == 0
    return path


def test_accuracy_test_prints_the_table_beside_the_thesis_s(truth_file, capsys):
    capsys.readouterr()
    assert main(["accuracy-test", "--sim-truth", str(truth_file), "--dofs", "z"]) == 0
    out = capsys.readouterr().out
    assert "twin" in out and "hybrid (3-8)" in out and "DLS (3-9)" in out and "geometric (3-10)" in out
    assert "planner profile thesis-t132, twin truth" in out  # which profile was tested (it named only the truth)
    lines = {ln.split()[0]: ln for ln in out.splitlines() if ln[:5].strip() in ("x", "z", "roll", "pitch")}
    assert set(lines) == {"x", "z", "roll", "pitch"}  # z deflected; the others held (marked so)
    hybrid = next(ln for ln in out.splitlines() if ln.startswith("z") and "hybrid (3-8)" in ln)
    assert "8.4" in hybrid  # the thesis's hybrid |E| of z, 8.36 mm


def test_accuracy_test_json_has_the_columns_and_the_thesis_figures(capsys):
    assert main(["accuracy-test", "--dofs", "x", "--instrument", "total-station", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["instrument"] == "total-station" and len(out["poses"]) == 4
    assert set(out["statistics"]["x"]) == {"E", "abs_E", "abs_E_max", "TT", "n"}
    assert out["thesis"]["geometric (3-10)"]["z"]["abs_E_max"] == pytest.approx(0.055)
    # a total station (σ 1 mm) on the nominal twin: x within millimetres
    assert out["statistics"]["x"]["abs_E_max"] < 0.006


def test_accuracy_test_bad_arguments_name_the_field(capsys):
    assert main(["accuracy-test", "--dofs", "yaw"]) == 2
    assert "dofs" in capsys.readouterr().err
    assert main(["accuracy-test", "--instrument", "laser"]) == 2


def test_calibrate_sensors_writes_a_profile_with_the_truth_s_counts(truth_file, tmp_path, capsys):
    out_path, progress = tmp_path / "calibrated.toml", tmp_path / "progress.json"
    argv = ["calibrate", "sensors", "--sim-truth", str(truth_file), "--actuators", "top"]
    assert main([*argv, "--out", str(out_path), "--progress", str(progress), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    truth, written = load_profile(truth_file), load_profile(out_path)
    t, w = truth.actuator("top"), written.actuator("top")
    assert abs(w.counts_min - t.counts_min) <= 1 and abs(w.counts_max - t.counts_max) <= 1
    assert res["actuators"]["top"]["counts_min"] == w.counts_min
    assert written.actuator("tilt") == load_profile("thesis-t132").actuator("tilt")  # only what was calibrated
    assert json.loads(progress.read_text())["actuators"]["top"]["fit"]["counts_max"] == w.counts_max
    # the written profile carries its provenance (it had none: nothing told it from the nominal one)
    line = next(ln for ln in out_path.read_text().splitlines() if ln.startswith("#! sensor_calibration ="))
    prov = tomllib.loads("p =" + line[len("#! sensor_calibration =") :])["p"]
    assert prov["on"].startswith("the simulated twin (truth ") and prov["detached"] is False and prov["date"]
    top = prov["actuators"]["top"]
    assert (top["counts_min"], top["counts_max"]) == (w.counts_min, w.counts_max) and top["high_stopped_by"]
    assert res["on"] == prov["on"]
    # calibrating it again replaces the line, never stacks a second one
    again = tmp_path / "again.toml"
    argv2 = ["calibrate", "sensors", "--sim-truth", str(truth_file), "--actuators", "top", "--profile", str(out_path)]
    assert main([*argv2, "--out", str(again), "--json"]) == 0
    assert again.read_text().count("#! sensor_calibration =") == 1


def test_calibrate_sensors_refuses_naming_the_limit(truth_file, tmp_path, capsys):
    out = tmp_path / "x.toml"
    argv = ["calibrate", "sensors", "--sim-truth", str(truth_file), "--actuators", "lift", "--out", str(out)]
    assert main(argv) == 2
    assert "top_link_pitch_max" in capsys.readouterr().err
    assert not out.exists()


def test_calibrate_sensors_refuses_an_out_that_is_no_profile_file_before_anything_moves(
    truth_file, tmp_path, capsys, monkeypatch
):
    """A commissioning trial: ``--out sensors.csv`` crept all ten stroke ends (30 s on the twin, ~3 min on a
    tractor) and only then said the name must end in .toml; nothing was kept."""
    from bridge.cli import commissioning

    def no_machine(*_a, **_k):
        raise AssertionError("the machine was started for an --out that cannot be written")

    monkeypatch.setattr(commissioning, "_truth", no_machine)
    out = tmp_path / "sensors.csv"
    assert main(["calibrate", "sensors", "--sim-truth", str(truth_file), "--detached", "--yes", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--out profile file {out}: the name must end in .toml" in err and not out.exists(), err


def test_calibrate_sensors_does_not_write_over_a_calibration_or_the_truth_before_anything_moves(
    truth_file, tmp_path, capsys, monkeypatch
):
    """A commissioning trial: ``calibrate sensors --out tractor.toml`` replaced a geometry-calibrated profile (its
    fit and provenance) with the nominal geometry and new counts, and ``--out`` the ``--sim-truth`` file replaced
    the twin's truth, each without a word. Refused before anything moves; ``--force`` writes over a calibration."""
    from bridge.cli import commissioning

    def no_machine(*_a, **_k):
        raise AssertionError("the machine was started for an --out that would be refused")

    monkeypatch.setattr(commissioning, "_truth", no_machine)
    calibrated = tmp_path / "tractor.toml"
    calibrated.write_text('#! calibration = { date = "2026-12-07", poses = 20 }\nschema_version = 1\n')
    before = calibrated.read_text()
    argv = ["calibrate", "sensors", "--sim-truth", str(truth_file), "--actuators", "top"]
    assert main([*argv, "--out", str(calibrated)]) == 2
    err = capsys.readouterr().err
    assert f"--out {calibrated} exists and holds a geometry calibration" in err and "--force" in err, err
    assert calibrated.read_text() == before
    assert main([*argv, "--out", str(truth_file), "--force"]) == 2
    assert "is the twin's true machine (--sim-truth)" in capsys.readouterr().err
    monkeypatch.undo()
    assert main([*argv, "--out", str(calibrated), "--force"]) == 0
    assert "#! sensor_calibration" in calibrated.read_text()


class _Terminal:
    """A stand-in for the operator's terminal on stdin: ``tty`` or not, answering ``answer``."""

    def __init__(self, answer: str, tty: bool = True) -> None:
        self.answer, self.tty = answer, tty

    def isatty(self) -> bool:
        return self.tty

    def readline(self) -> str:
        return self.answer


def test_calibrate_sensors_detached_calibrates_the_lift_the_pinned_calibration_refuses(truth_file, tmp_path, capsys):
    out_path = tmp_path / "calibrated.toml"
    argv = ["calibrate", "sensors", "--sim-truth", str(truth_file), "--actuators", "lift", "--out", str(out_path)]
    assert main([*argv, "--detached", "--yes", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    truth, written = load_profile(truth_file), load_profile(out_path)
    t, w = truth.actuator("lift"), written.actuator("lift")
    assert abs(w.counts_min - t.counts_min) <= 1 and abs(w.counts_max - t.counts_max) <= 1
    assert res["detached"] is True and res["actuators"]["lift"]["counts_max"] == w.counts_max
    assert res["actuators"]["lift"]["low"]["stopped_by"] == res["actuators"]["lift"]["high"]["stopped_by"] == "relay"
    # the written profile keeps the thesis's top-link limits: --detached released them for the calibration only
    assert written.limits == load_profile("thesis-t132").limits


def test_calibrate_sensors_detached_is_refused_with_an_implement(tmp_path, capsys):
    argv = ["calibrate", "sensors", "--actuators", "lift", "--out", str(tmp_path / "x.toml"), "--detached", "--yes"]
    assert main([*argv, "--implement", "plough"]) == 2
    err = capsys.readouterr().err
    assert "--detached declares that no implement is attached: it cannot go with --implement plough" in err
    assert not (tmp_path / "x.toml").exists()


def test_calibrate_sensors_detached_needs_the_operator_s_confirmation(tmp_path, capsys, monkeypatch):
    argv = ["calibrate", "sensors", "--actuators", "yaw", "--out", str(tmp_path / "x.toml"), "--detached"]
    monkeypatch.setattr("sys.stdin", _Terminal("", tty=False))
    assert main(argv) == 2
    assert "confirm it with --yes" in capsys.readouterr().err
    monkeypatch.setattr("sys.stdin", _Terminal("n\n"))
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "top link is unpinned" in err and "--detached not confirmed: nothing moved" in err
    # confirmed: the command goes on (and stops at the next bad argument, the unknown actuator)
    monkeypatch.setattr("sys.stdin", _Terminal("y\n"))
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "not confirmed" not in err and "--actuators 'yaw': unknown 'yaw'" in err
    # --yes confirms only --detached
    assert main(["calibrate", "sensors", "--actuators", "lift", "--out", str(tmp_path / "x.toml"), "--yes"]) == 2
    assert "nothing to confirm" in capsys.readouterr().err
    assert not (tmp_path / "x.toml").exists()


def test_an_interrupted_commissioning_command_says_what_it_left(monkeypatch, capsys, tmp_path):
    """Ctrl-C on ``calibrate sensors`` (and the other commissioning commands) exited 130 without a word; the
    engineer could not tell that the progress file lets it resume (a commissioning engineer's report)."""
    import bridge.cli.calibrate as calibrate_cli
    import bridge.cli.commissioning as commissioning_cli

    def interrupted(_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(commissioning_cli, "_cmd_calibrate_sensors", interrupted)
    progress = tmp_path / "p.json"
    argv = ["calibrate", "sensors", "--progress", str(progress), "--out", str(tmp_path / "s.toml")]
    assert main(argv) == 130  # before the first end: the file it named had never been written (a trial's report)
    assert f"no end was found yet ({progress} was not written)" in capsys.readouterr().err
    progress.write_text("{}")
    assert main(argv) == 130
    err = capsys.readouterr().err.strip()
    assert err.startswith("hitch: interrupted: no profile was written") and f"{progress}: run the same command" in err
    assert main(["calibrate", "sensors", "--out", str(tmp_path / "s.toml")]) == 130
    assert "with --progress FILE an interrupted calibration resumes" in capsys.readouterr().err
    monkeypatch.setattr(calibrate_cli, "_cmd_geometry", interrupted)
    assert main(["calibrate", "geometry", "--measurements", "m.csv", "--out", str(tmp_path / "c.toml")]) == 130
    assert capsys.readouterr().err.strip() == "hitch: interrupted: nothing was written"


def test_sigterm_ends_a_commissioning_command_as_ctrl_c_does_and_says_so(monkeypatch, capsys, tmp_path):
    """SIGTERM (a supervisor, kill) during calibrate sensors over a bus ended it without a word (a commissioning
    trial); it now interrupts it as Ctrl-C does: its clean-up runs, it says what it left, status 143."""
    import os
    import signal
    import time

    import bridge.cli.commissioning as commissioning_cli

    def killed(_args):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler interrupts this
        raise AssertionError("SIGTERM did not interrupt the command")

    monkeypatch.setattr(commissioning_cli, "_cmd_calibrate_sensors", killed)
    before = signal.getsignal(signal.SIGTERM)
    assert main(["calibrate", "sensors", "--out", str(tmp_path / "s.toml")]) == 143
    assert capsys.readouterr().err.startswith("hitch: terminated: no profile was written")
    assert signal.getsignal(signal.SIGTERM) is before  # the old handler is back


@pytest.mark.parametrize(
    "args",
    [
        ["calibrate", "sensors", "--detached", "--yes", "--actuators", "top", "--out", "{missing}/x.toml"],
        ["calibrate", "sensors", "--actuators", "top", "--progress", "{missing}/p.json", "--out", "{ok}/x.toml"],
        ["calibrate", "measure-twin", "--sim-truth", "{truth}", "--out", "{missing}/m.csv"],
        ["calibrate", "plan-poses", "--n", "4", "--out", "{missing}/plan.csv"],
        ["calibrate", "geometry", "--measurements", "{ok}/m.csv", "--out", "{missing}/g.toml"],
    ],
)
def test_an_output_in_a_missing_folder_is_refused_before_anything_moves(args, truth_file, tmp_path, capsys):
    """A commissioning trial: calibrate sensors crept to all ten end stops (minutes on a tractor), and
    measure-twin drove 16 s of gotos, before finding that --out's folder did not exist; the work was lost."""
    missing = tmp_path / "nodir"
    filled = [a.format(missing=missing, ok=tmp_path, truth=truth_file) for a in args]
    assert main(filled) == 2
    err = capsys.readouterr().err
    assert f"the folder {str(missing)!r} does not exist" in err, err
    assert not missing.exists() and not (tmp_path / "x.toml").exists()


@pytest.mark.parametrize(
    "given, expected",
    [
        ("lift,tlt", "--actuators 'lift,tlt': unknown 'tlt'; allowed: lift, tilt, top, left, right"),
        ("top,top", "--actuators 'top,top': 'top' given more than once"),
        (",", "--actuators ',': none given"),
        ("", "--actuators '': none given"),  # not "all five" on a command that drives each to its ends (a review)
    ],
)
def test_calibrate_sensors_names_only_the_unknown_or_repeated_actuators(given, expected, tmp_path, capsys):
    """A commissioning trial: 'lift,tlt' was refused as "unknown or none ['lift', 'tlt']" (the valid lift listed
    as unknown), and 'top,top' was accepted."""
    assert main(["calibrate", "sensors", "--actuators", given, "--out", str(tmp_path / "s.toml")]) == 2
    assert expected in capsys.readouterr().err


def test_commissioning_output_is_not_wrapped_into_a_pipe(truth_file, tmp_path, capsys):
    """A commissioning trial: 'profile written to s.toml (calibrated … (truth \\ntruth.toml))' was cut at 80
    columns into a pipe, which broke grep."""
    out = tmp_path / ("a-rather-long-folder-name-" * 3) / "s.toml"
    out.parent.mkdir()
    argv = ["calibrate", "sensors", "--sim-truth", str(truth_file), "--actuators", "top", "--out", str(out)]
    assert main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.startswith("profile written to ") and line.endswith(")") for line in lines), lines
