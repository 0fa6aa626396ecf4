"""``hitch track``: argument errors (sine specs, CSV files with line and column, rate and TTL bounds),
the sine and CSV signal generators against closed forms, ``--dry-run``, and (slow) a 2 s sine streamed to
a real ``hitch serve`` that ends with the motion finished and every put counted by the service."""

from __future__ import annotations

import argparse
import json
import math
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from bridge.cli.errors import CLIError
from bridge.cli.main import main
from bridge.cli.track import (
    CsvSignal,
    SineSignal,
    SineTerm,
    parse_dofs,
    parse_sine,
    read_signal_csv,
    setpoints,
)
from tests.integration.service_process import ROOT, ServiceProcess, free_port, wait_online


def _err(capsys, *argv: str) -> str:
    assert main(["track", *argv]) == 2
    out = capsys.readouterr()
    assert out.out == ""
    return out.err


# ---------------------------------------------------------------------------------------- sine specs
def test_sine_spec_parses_terms_in_si():
    assert parse_sine("x=0.02@0.05Hz,roll=0.01@0.1hz") == (SineTerm("x", 0.02, 0.05), SineTerm("roll", 0.01, 0.1))
    assert parse_sine(" z = 0.05 @ 2 ") == (SineTerm("z", 0.05, 2.0),)


@pytest.mark.parametrize(
    ("spec", "words"),
    [
        ("y=0.01@1Hz", "unknown DOF 'y'; allowed: x, z, roll, pitch"),
        ("x=0.01@1Hz,x=0.02@1Hz", "DOF 'x' given twice"),
        ("z=20@0.5Hz", "amplitude must lie in (0, 0.5] m, got 20 (SI units: m, not mm or deg)"),
        ("roll=0@0.5Hz", "amplitude must lie in (0, 0.5] rad, got 0"),
        ("z=0.01@0Hz", "frequency must lie in (0, 10] Hz, got 0"),
        ("z=0.01@11Hz", "frequency must lie in (0, 10] Hz, got 11"),
        ("z=abc@1Hz", "amplitude and frequency must be numbers"),
        ("z=0.01", "is not DOF=AMPLITUDE@FREQUENCYHz"),
        ("z=nan@1Hz", "amplitude must lie in (0, 0.5] m"),
        (",", "no terms given"),
        # a velocity beyond what a setpoint may carry: shown by --dry-run, refused by the service mid-session
        ("roll=0.5@0.5Hz", "roll: its velocity 2π·f·A = 1.571 rad/s exceeds the ±1 rad/s a setpoint may carry: "),
        ("z=0.5@10Hz", "at 10 Hz the amplitude must be at most 0.01592 m"),
    ],
)
def test_bad_sine_specs_name_the_flag_and_the_range(capsys, spec, words):
    with pytest.raises(argparse.ArgumentTypeError, match="--sine"):
        parse_sine(spec)
    err = _err(capsys, "--sine", spec, "--dry-run")
    assert "--sine" in err and words in err, err


def test_a_rate_of_exactly_two_setpoints_per_ttl_is_taken(capsys):
    """A new user's report: --rate 13.3333333333 --ttl-ms 150 (75.0000000002 ms, exactly half in ten digits) was
    refused as "more than half", and the message proposed the rate it refused."""
    from bridge.cli.main import main

    assert main(["track", "--sine", "z=0.02@1Hz", "--rate", "13.3333333333", "--ttl-ms", "150", "--dry-run"]) == 0
    capsys.readouterr()


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--rate", "0"], "--rate must lie in (0, 100] Hz, got 0"),
        (["--rate", "100.5"], "--rate must lie in (0, 100] Hz, got 100.5"),
        (["--rate", "inf"], "--rate must be finite"),
        (["--rate", "5"], "--rate 5 Hz sends a setpoint every 200 ms, more than half of --ttl-ms 200 ms"),
        (["--ttl-ms", "49"], "--ttl-ms must lie in [50, 1000] ms, got 49"),
        (["--ttl-ms", "1001"], "--ttl-ms must lie in [50, 1000] ms, got 1001"),
        (["--duration", "0"], "--duration must lie in (0, 3600] s"),
        (["--dof", "x,q"], "--dof: unknown DOF 'q'"),
        (["--dof", "x"], "--sine names z, which --dof x does not track"),
        (["--frame", "moon"], "invalid choice: 'moon'"),
        (
            ["--rate", "2", "--ttl-ms", "1000", "--sine", "z=0.01@1.5Hz"],
            "1.5 Hz is above half the setpoint rate (--rate 2 Hz: at most 1 Hz)",
        ),
        (["--frame", "ground"], "--frame ground: z is the height above the ground"),
        (["--around", "x=0.01"], "--around names x, which --dof z does not track"),
        # before: streamed (z = 5.009635 in --dry-run), then refused by the service as "track/setpoint: pose.z"
        (["--around", "z=5"], "--around z = 5 m lies outside [-2, 2] m"),
        (["--around", "z=250"], "did you mean mm? 250 mm = 0.25 m"),
        (["--frame", "level", "--dof", "roll", "--sine", "roll=0.01@0.1Hz", "--around", "roll=1e308"], "roll = 1e+308"),
    ],
)
def test_bad_options_name_the_flag_and_the_allowed_range(capsys, argv, words):
    base = ["--sine", "z=0.02@0.5Hz"] if "--sine" not in argv else []
    err = _err(capsys, *base, *argv, "--dry-run")
    assert words in err, err


def test_exactly_one_signal(capsys, tmp_path):
    assert "give exactly one signal" in _err(capsys, "--dry-run")
    f = tmp_path / "s.csv"
    f.write_text("t,z\n0,0.1\n1,0.2\n")
    assert "give exactly one signal" in _err(capsys, "--sine", "z=0.01@1Hz", "--from-file", str(f), "--dry-run")


def test_dofs_are_canonical_and_unique():
    assert parse_dofs("pitch,x") == ("x", "pitch")
    with pytest.raises(argparse.ArgumentTypeError, match="at most once"):
        parse_dofs("x,x")


# ---------------------------------------------------------------------------------------- CSV errors
@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("t,z_mm\n0,100\n", "line 1, column 2 ('z_mm'): only SI units"),
        ("t,z [m]\n0,0.1\n", "line 1, column 2 ('z [m]'): only SI units"),
        ("t_s,roll_deg\n0,1\n", "line 1, column 2 ('roll_deg'): only SI units"),
        ("# a comment\n\nt,roll,q\n0,0,1\n", "line 3, column 3: unknown column 'q'"),
        ("t,z\n0,0.1\n0.5,abc\n", "line 3, column 2 (z): not a number: 'abc'"),
        ("t,z\n0,0.1\n0.5,nan\n", "line 3, column 2 (z): must be finite"),
        ("t,z\n0,0.1\n0.5,0.2\n0.5,0.3\n", "line 4, column 1 (t): t must increase strictly, got 0.5 s after 0.5 s"),
        ("t,z\n-1,0.1\n0,0.2\n", "line 2, column 1 (t): t must be >= 0 s"),
        ("t,z\n0,0.1\n1,0.2,3\n", "line 3: 3 values, the header has 2 columns"),
        ("z,roll\n0.1,0\n0.2,0\n", "line 1: no 't' column"),
        ("t,v_z\n0,0\n1,0\n", "line 1: no DOF column"),
        ("t,z,v_roll\n0,0.1,0\n1,0.1,0\n", "line 1, column 3: v_roll without a roll column"),
        ("t,z,z\n0,0.1,0.1\n", "line 1, column 3: column 'z' given twice"),
        ("t,z\n0,0.1\n", "needs at least 2 rows"),
        ("", "empty"),
        # values beyond what a setpoint may carry: refused at load (the old CLI started the session first)
        ("t,z\n0.0,100\n0.5,110\n", "line 2, column 2 (z): 100 m is outside [-2, 2] m (SI units); did you mean mm?"),
        ("t,z,v_z\n0,0.1,50\n1,0.1,0\n", "line 2, column 3 (v_z): 50 m/s is outside [-1, 1] m/s"),
        ("t,roll\n0,0\n1,5\n", "line 3, column 2 (roll): 5 rad is outside [-1.571, 1.571] rad (SI units); did you"),
    ],
)
def test_csv_errors_name_the_file_line_and_column(capsys, tmp_path, text, words):
    f = tmp_path / "signal.csv"
    f.write_text(text)
    with pytest.raises(CLIError) as exc:
        read_signal_csv(f)
    assert str(f) in str(exc.value) and words in str(exc.value), str(exc.value)
    err = _err(capsys, "--from-file", str(f), "--dry-run")
    assert words in err


def test_around_a_dof_the_file_gives_is_refused_and_around_a_held_dof_is_taken(capsys, tmp_path):
    """A new user's report: --from-file signal.csv --around z=0.2 played the file's z and said nothing."""
    f = tmp_path / "signal.csv"
    f.write_text("t,z\n0,0.10\n1,0.12\n")
    err = _err(capsys, "--from-file", str(f), "--around", "z=0.2", "--dry-run")
    assert f"--around z: {f} gives z itself (absolute values)" in err, err
    from bridge.cli.main import main

    assert main(["track", "--from-file", str(f), "--dof", "z,roll", "--around", "roll=0.01", "--dry-run"]) == 0
    assert "roll=+0.010000" in capsys.readouterr().out  # the held roll at its --around value


def test_columns_may_carry_their_si_unit_as_the_scenario_csvs_do(tmp_path):
    """A new user's report: the scenario CSVs require "time_s,speed_m_s", this file refused "t_s"."""
    f = tmp_path / "signal.csv"
    f.write_text("t_s,z_m,roll_rad,v_z_m_s\n0,0.10,0.01,0.02\n1,0.12,0.01,0.02\n")
    sig = read_signal_csv(f)
    assert set(sig.positions) == {"z", "roll"} and set(sig.velocities) == {"z"} and sig.span_s == 1.0
    assert sig.sample(0.5)[0] == pytest.approx({"z": 0.11, "roll": 0.01})


def test_a_missing_file_is_named(capsys, tmp_path):
    assert f"--from-file {tmp_path / 'nope.csv'}: does not exist" in _err(
        capsys, "--from-file", str(tmp_path / "nope.csv"), "--dry-run"
    )
    # a folder and a device exist: said so, not "no such file" (a fuzz trial)
    assert f"--from-file {tmp_path}: is a folder" in _err(capsys, "--from-file", str(tmp_path), "--dry-run")
    assert "--from-file /dev/zero: is not a regular file" in _err(capsys, "--from-file", "/dev/zero", "--dry-run")


def test_duration_beyond_the_file_is_refused(capsys, tmp_path):
    f = tmp_path / "s.csv"
    f.write_text("t,z\n0,0.1\n1,0.2\n")
    assert "--duration 2 s is longer than" in _err(capsys, "--from-file", str(f), "--duration", "2", "--dry-run")


# ---------------------------------------------------------------------------------------- generators
def test_sine_signal_matches_its_closed_form_and_its_velocity_is_the_derivative():
    terms = (SineTerm("x", 0.02, 0.05), SineTerm("roll", 0.01, 0.7))
    sig = SineSignal(terms, {"x": 0.01, "z": 0.2, "roll": -0.003}, held=("z",), duration_s=3.0)
    assert sig.dofs == ("x", "z", "roll")
    for t in np.linspace(0.0, 3.0, 31):
        pose, vel = sig.sample(float(t))
        assert pose["x"] == pytest.approx(0.01 + 0.02 * math.sin(2 * math.pi * 0.05 * t), abs=1e-15)
        assert pose["roll"] == pytest.approx(-0.003 + 0.01 * math.sin(2 * math.pi * 0.7 * t), abs=1e-15)
        assert pose["z"] == 0.2 and vel is not None and vel["z"] == 0.0
        h = 1e-6  # central difference of the pose: the velocity sent with it
        p1, _ = sig.sample(float(t) + h)
        p0, _ = sig.sample(float(t) - h)
        for k in ("x", "roll"):
            assert vel[k] == pytest.approx((p1[k] - p0[k]) / (2 * h), rel=1e-6, abs=1e-12)


def test_setpoints_come_at_the_rate_with_increasing_seq_until_the_duration():
    sig = SineSignal((SineTerm("z", 0.02, 0.5),), {"z": 0.1}, duration_s=2.0)
    sps = list(setpoints(sig, 50.0))
    assert len(sps) == 101 and [s[0] for s in sps] == list(range(101))
    assert [s[1] for s in sps] == pytest.approx([k / 50 for k in range(101)])
    assert sps[25][2]["pose"]["z"] == pytest.approx(0.1 + 0.02 * math.sin(2 * math.pi * 0.5 * 0.5))
    assert len(list(setpoints(sig, 50.0, 0.5))) == 26


def test_a_byte_order_mark_is_allowed(tmp_path):
    """The old reader refused a spreadsheet's "CSV UTF-8" header: unknown column '\ufefft'."""
    f, g = tmp_path / "a.csv", tmp_path / "b.csv"
    f.write_text("t,z\n0,0.1\n1,0.2\n", encoding="utf-8")
    g.write_text("\ufefft,z\n0,0.1\n1,0.2\n", encoding="utf-8")
    a, b = read_signal_csv(f), read_signal_csv(g)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.positions["z"], b.positions["z"])


def test_csv_interpolation_against_closed_forms(tmp_path):
    # piecewise-linear data is reproduced exactly between its rows; velocities interpolate the same way
    f = tmp_path / "lin.csv"
    f.write_text("t,z,v_z,roll\n1.0,0.10,0.02,0.0\n2.0,0.12,0.02,0.01\n4.0,0.16,0.02,-0.01\n")
    sig = read_signal_csv(f)
    assert isinstance(sig, CsvSignal) and sig.span_s == 3.0 and sig.dofs == ("z", "roll")
    for t in np.linspace(0.0, 3.0, 61):  # played from the first row's time
        pose, vel = sig.sample(float(t))
        assert pose["z"] == pytest.approx(0.10 + 0.02 * t, abs=1e-12)
        roll = 0.01 * t if t <= 1 else 0.01 - 0.01 * (t - 1)
        assert pose["roll"] == pytest.approx(roll, abs=1e-12)
        assert vel == {"z": pytest.approx(0.02)}
    # a sine sampled at 100 Hz: linear interpolation is within A·ω²·h²/8 of the sine
    a, fr, h = 0.02, 0.5, 0.01
    ts = np.arange(0.0, 2.0 + h / 2, h)
    g = tmp_path / "sine.csv"
    g.write_text("t,x\n" + "\n".join(f"{t:.6f},{a * math.sin(2 * math.pi * fr * t):.12f}" for t in ts) + "\n")
    sine = read_signal_csv(g)
    bound = a * (2 * math.pi * fr) ** 2 * h * h / 8 + 1e-11
    for _, t, body in setpoints(sine, 33.0):
        assert abs(body["pose"]["x"] - a * math.sin(2 * math.pi * fr * t)) <= bound
        assert "velocity" not in body


def test_dry_run_prints_the_first_setpoints_without_connecting(capsys):
    assert main(["track", "--frame", "level", "--sine", "roll=0.01@0.1Hz", "--rate", "20", "--dry-run", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frame"] == "level" and out["dof"] == ["roll"] and out["centre"] == {"roll": 0.0}  # level: around 0
    rows = out["setpoints"]
    assert [r["seq"] for r in rows] == list(range(10))
    for r in rows:
        assert r["pose"]["roll"] == pytest.approx(0.01 * math.sin(2 * math.pi * 0.1 * r["t"]))
    assert main(["track", "--dof", "z,roll", "--sine", "z=0.02@0.5Hz", "--around", "z=0.2", "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "centre of roll shown as 0: the start pose is added when it runs" in text
    assert "    0  t=   0.000  z=+0.200000  roll=+0.000000" in text


DOC_CSV = "t,z,v_z,roll\n0.0,0.10,0.02,0.000\n0.5,0.11,0.02,0.005\n1.0,0.12,0.02,0.000\n"  # docs/tracking.md


def test_dry_run_of_the_documented_csv_shows_the_velocities_it_has(capsys, tmp_path):
    """A new user's report: the docs' CSV (a velocity for z, none for roll) ended the dry run with
    KeyError: 'roll'."""
    f = tmp_path / "signal.csv"
    f.write_text(DOC_CSV, encoding="utf-8")
    assert main(["track", "--from-file", str(f), "--rate", "10", "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "    5  t=   0.500  z=+0.110000  roll=+0.005000  v: z=+0.020000" in text


# ---------------------------------------------------------------------------------------- a real service
def _track(endpoint: str, *args: str) -> subprocess.CompletedProcess:
    """``hitch track ARGS`` against the service at ``endpoint``, as a user runs it (its own process)."""
    return subprocess.run(
        [sys.executable, "-m", "bridge.cli", "track", *args, "--connect", endpoint, "--timeout", "20"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.slow
def test_a_two_second_sine_streams_to_a_real_service_and_ends_with_the_motion_finished(tmp_path):
    from bridge.service.client import HitchClient

    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    svc = ServiceProcess(
        ["--listen", endpoint, "--data-dir", str(tmp_path / "data"), "--can-channel", f"track-cli-{port}"],
        ready_timeout_s=120.0,
    )
    try:
        with HitchClient([endpoint], timeout_s=10.0) as c:
            start = wait_online(c, 60.0)
        r = _track(endpoint, "--sine", "z=0.02@0.5Hz", "--duration", "2", "--json")
        assert r.returncode == 0, r.stderr
        out = json.loads(r.stdout)
        assert out["finished"] and out["reason"] == "track/stop"
        assert out["outcome"]["event"] == "motion_finished" and out["outcome"]["kind"] == "track"
        # the first setpoint is a query, the rest are puts: the service counts every one it took
        assert out["sent"] >= 50 and out["track"]["setpoints"] == out["sent"], out
        assert out["track"]["rejected"] == 0 and out["track"]["ignored_seq"] == 0
        assert out["streamed_s"] == pytest.approx(2.0, abs=0.03)
        assert abs(out["pose"]["z"] - start["pose"]["z"]) < 0.03  # around the start height, amplitude 20 mm
        assert set(out["end_gap"]) == {"z"} and abs(out["end_gap"]["z"]) < 0.02
        with HitchClient([endpoint], timeout_s=10.0) as c:
            st = c.state()
            assert st.get("track") is None and not st["moving"]

        # the documented CSV without --duration: the whole file plays (a new user's report: it ended with
        # "TypeError: unsupported format string passed to NoneType.__format__" after starting the session)
        csv = tmp_path / "signal.csv"
        csv.write_text(DOC_CSV, encoding="utf-8")
        r = _track(endpoint, "--from-file", str(csv), "--rate", "50")
        assert r.returncode == 0, (r.stdout, r.stderr)
        assert ", 50 Hz, 1 s" in r.stdout and "finished: track/stop" in r.stdout, r.stdout
        assert "ended away from the last setpoint" not in r.stderr, r.stderr  # it starts near the file's z
        # a file 80…100 mm above where the hitch stands, 1 s long (z moves at most ~47 mm/s): it ends far from the
        # last row, and says so (a new user's report: "finished", exit 0, nothing said about ending 116 mm away)
        z0 = out["pose"]["z"]
        far = tmp_path / "far.csv"
        far.write_text(f"t,z\n0.0,{z0 + 0.08:.4f}\n1.0,{z0 + 0.10:.4f}\n", encoding="utf-8")
        r = _track(endpoint, "--from-file", str(far), "--rate", "50")
        assert r.returncode == 0 and "finished: track/stop" in r.stdout, (r.stdout, r.stderr)
        assert "hitch: note: the hitch ended away from the last setpoint sent (z -" in r.stderr, r.stderr
        # setpoints the service rejects: the summary says why (a new user's report: only `hitch log` did)
        # (z = 1.5 m: within what a setpoint may carry, far beyond what the follower takes in the tractor frame)
        bad = tmp_path / "bad.csv"
        bad.write_text("t,z\n0.0,0.10\n0.1,0.10\n0.2,1.5\n1.0,1.5\n", encoding="utf-8")
        r = _track(endpoint, "--from-file", str(bad), "--rate", "50")
        assert "last rejection: " in r.stdout and "rejected 0" not in r.stdout, (r.stdout, r.stderr)
        # a value no setpoint may carry (50 m: mm meant) is refused at load, before any session starts
        bad.write_text("t,z\n0.0,0.10\n0.1,0.10\n0.2,50.0\n1.0,50.0\n", encoding="utf-8")
        r = _track(endpoint, "--from-file", str(bad), "--rate", "50")
        assert r.returncode == 2 and "line 4, column 2 (z): 50 m is outside [-2, 2] m" in r.stderr, r.stderr
        assert "did you mean mm?" in r.stderr and r.stdout == ""

        # Ctrl-C mid-stream: track/stop is sent and awaited, then exit 130; SIGTERM (a supervisor, kill) the
        # same (it exited silently, the service braking at the ttl: a new user's report)
        for sig in (signal.SIGINT, signal.SIGTERM):
            so, se, rc = _interrupted_stream(endpoint, sig)
            assert rc == 130, se
            assert "sending track/stop" in se and "finished: track/stop" in so, (sig, so, se)
    finally:
        svc.kill()


def _interrupted_stream(endpoint: str, sig: int) -> tuple[str, str, int]:
    """``hitch track --sine`` sent ``sig`` once it streams: its stdout, stderr and exit code."""
    p = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", "track", "--sine", "z=0.02@0.5Hz", "--connect", endpoint]
        + ["--timeout", "20"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    line = ""
    while time.monotonic() < deadline and "sent" not in line:  # the first progress line: it streams
        line = p.stdout.readline() if p.stdout else ""
    p.send_signal(sig)
    so, se = p.communicate(timeout=60)
    return so, se, p.returncode


# ---------------------------------------------------------------------------------------- a new user's trial
@pytest.mark.parametrize(
    ("text", "rate", "times", "last_z"),
    [
        ("t,z\n0,0.1\n0.05,0.2\n", "50", [0.0, 0.02, 0.04, 0.05], 0.2),  # sent 0.1, 0.14, 0.18: never 0.2
        ("t,z\n0,0.1\n0.033,0.11\n0.077,0.12\n", "10", [0.0, 0.077], 0.12),  # sent 0.1 alone
    ],
)
def test_the_last_row_is_sent_when_the_file_is_no_whole_number_of_periods(capsys, tmp_path, text, rate, times, last_z):
    f = tmp_path / "s.csv"
    f.write_text(text)
    assert main(["track", "--from-file", str(f), "--rate", rate, "--dry-run", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["setpoints"]
    assert [r["t"] for r in rows] == pytest.approx(times) and [r["seq"] for r in rows] == list(range(len(times)))
    assert rows[-1]["pose"]["z"] == pytest.approx(last_z)
    # a --duration that is no whole number of periods ends at its own time, the signal's value there
    sps = list(setpoints(read_signal_csv(f), 100.0, 0.025))
    assert sps[-1][1] == pytest.approx(0.025) and len(sps) == 4
    # a whole number of periods: no extra setpoint
    sig = SineSignal((SineTerm("z", 0.02, 0.5),), {"z": 0.1}, duration_s=2.0)
    assert len(list(setpoints(sig, 50.0))) == 101


@pytest.mark.parametrize("cell", ["1_0", "0.1_5", "\u0661\u0660", "\uff11"])  # separators, Arabic-Indic, full-width
def test_a_number_python_reads_but_no_csv_writes_is_refused(capsys, tmp_path, cell):
    """A new user's report: the value 1_0 was read as 10 (Python's float takes digit separators)."""
    f = tmp_path / "signal.csv"
    f.write_text(f"t,z\n0,0.1\n1,{cell}\n", encoding="utf-8")
    words = f"line 3, column 2 (z): not a number: {cell!r}"
    with pytest.raises(CLIError, match=re.escape(words)):
        read_signal_csv(f)
    assert words in _err(capsys, "--from-file", str(f), "--dry-run")
    f.write_text("t,z\n 0 ,+.1\n1e0,1.5E-1\n2.,-0.0\n")  # what a CSV writer may write is still read
    assert read_signal_csv(f).positions["z"].tolist() == [0.1, 0.15, 0.0]


def test_a_file_longer_than_the_longest_run_is_refused_naming_the_limit(capsys, tmp_path):
    """A new user's report: a file spanning 1e9 s was taken and played whole, while --duration is capped at 3600 s."""
    f = tmp_path / "long.csv"
    f.write_text("t,z\n0,0.1\n1e9,0.2\n")
    err = _err(capsys, "--from-file", str(f), "--dry-run")
    assert f"--from-file {f}: the file spans 1e+09 s" in err and "more than the 3600 s a track run may last" in err
    f.write_text("t,z\n5,0.1\n3605,0.2\n")  # an hour from its first row: taken
    assert main(["track", "--from-file", str(f), "--dry-run"]) == 0
    capsys.readouterr()
    f.write_text("t,z\n5,0.1\n3605.5,0.2\n")
    assert "the file spans 3600.5 s" in _err(capsys, "--from-file", str(f), "--dry-run")
    assert main(["track", "--from-file", str(f), "--duration", "60", "--dry-run"]) == 0  # a part of it: taken
    capsys.readouterr()
