"""Operator-facing behaviour of ``hitch`` that needs no running service.

Truth: the values we pass in (a limit name the solver itself reports, text we write into an event
log, the options we give) must come out exactly as they are, and every refused option names
itself and its allowed range.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
import pytest

from bridge.cli import service as cli_service
from bridge.cli.main import main
from bridge.cli.output import console, esc
from bridge.service.blackbox import EventLog, event_log_path, read_events
from planner.model.exact_inverse import ExactInverse
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.profiles.hitch import load_profile
from tests.helpers import profile_file_with_final_approach
from tests.integration.service_process import free_port


class _FakeClient:
    """A stand-in for HitchClient as the CLI uses it (a context manager); tests add the calls they answer."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass


def _err_line(capsys) -> str:
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hitch: error: "), lines
    return lines[0]


# ---------------------------------------------------------------------------------------- markup
def test_a_limit_name_with_an_emoji_code_prints_as_it_is(capsys):
    # pitch 0.6 rad is beyond the top link's stroke: the solver names "stroke:top:min" (":top:" is 🔝)
    assert main(["ik", "--x", "0", "--z", "0.2", "--roll", "0", "--pitch", "0.6"]) == 0
    out = capsys.readouterr().out
    assert "stroke:top:min" in out and "🔝" not in out
    assert main(["ik", "--x", "0", "--z", "0.2", "--roll", "0", "--pitch", "0.6", "--json"]) == 0
    assert "stroke:top:min" in json.loads(capsys.readouterr().out)["active"]


def test_service_replies_and_state_lines_print_data_verbatim(capsys):
    args = argparse.Namespace(json=False)
    cli_service._print(args, {}, "limited: workspace:x:max [red]not markup[/red] :thumbs_up:")
    assert capsys.readouterr().out.strip() == "limited: workspace:x:max [red]not markup[/red] :thumbs_up:"
    state = {
        "seq": 3,
        "mode": "auto",
        "moving": True,
        "motion_id": 4,
        "pose": {"x": 0.0, "z": 0.1},
        "ecu": {"online": True, "faults": ["stale:x:[b]"]},
        "limited": {"workspace:x:max": "[bold]braking"},
    }
    cli_service._print(args, state, cli_service._state_line(state), markup=True)
    out = capsys.readouterr().out
    assert "stale:x:[b]" in out and "workspace:x:max: [bold]braking" in out and "❌" not in out


def test_a_state_at_rest_and_a_script_error_without_a_step_print_no_python_none(capsys):
    """A new user's report: a fresh service's state printed ``motion None``, and a script that is not YAML
    ``step None: …``."""
    args = argparse.Namespace(json=False)
    rest = {"seq": 1, "mode": "auto", "moving": False, "motion_id": None, "pose": {"z": 0.1}, "ecu": {"online": True}}
    cli_service._print(args, rest, cli_service._state_line(rest), markup=True)
    line = capsys.readouterr().out
    assert "None" not in line and "motion -" in line
    errors = [{"step": None, "message": "script is not valid YAML"}, {"step": 2, "message": "unknown step"}]
    # steps counted from 1 as a reader counts them, the API's index beside (a fuzz trial read "step 0")
    assert cli_service.script_errors(errors) == "  script: script is not valid YAML\n  step 3 (index 2): unknown step"


def test_the_state_line_names_a_running_maneuvers_step_as_validate_does():
    """The state line said ``maneuver m step 0`` for the step validate calls ``step 1 (index 0)``."""
    m = {"name": "m", "step": 0, "kind": "goto", "paused": True}
    assert cli_service._activity({"maneuver": m}) == "maneuver m step 1 (index 0) goto PAUSED"
    assert cli_service._activity({"maneuver": {"name": "m", "step": None}}) == "maneuver m step -"


def test_console_and_esc_helpers():
    c = console(record=True, width=200)
    c.print(f"[bold]{esc('[red]x[/red] :x:')}[/bold]")
    assert c.export_text().strip() == "[red]x[/red] :x:"


# ---------------------------------------------------------------------------------------- options
def test_a_repeated_pose_key_is_refused_naming_it(capsys):
    assert main(["plan", "--to", "x=0.01,x=0.02"]) == 2
    line = _err_line(capsys)
    assert "--to" in line and "'x' given twice" in line
    assert main(["goto", "--to", "z=0.1,roll=0,z=0.2"]) == 2
    assert "'z' given twice" in _err_line(capsys)


@pytest.mark.parametrize(
    "argv, needles",
    [
        (["jog", "--vz", "0.05", "--duration", "0"], ("--duration", "(0, 3600] s", "got 0")),
        (["jog", "--vz", "0.05", "--duration", "-1"], ("--duration", "(0, 3600] s")),
        (["jog", "--vz", "0.05", "--ttl-ms", "0"], ("--ttl-ms", "(0, 5000] ms")),
        (["jog", "--vz", "0.05", "--ttl-ms", "-50"], ("--ttl-ms", "(0, 5000] ms")),
        (["jog", "--vz", "0.05", "--ttl-ms", "nan"], ("--ttl-ms", "finite")),
        (["stop", "--timeout", "0"], ("--timeout", "(0, 600] s")),
        (["goto", "--to", "z=0.1", "--timeout", "-3"], ("--timeout", "(0, 600] s")),
        (["state", "--count", "-1"], ("--count", ">= 0")),
        # a new user's report: a negative N printed every record but the first N
        (["log", "--last", "-3"], ("--last", ">= 0", "got -3")),
        (["replay", "x.asc", "--stale-after", "0"], ("--stale-after", "(0, 10] s")),
        # the service's documented bound, not (0, 1] (a new user's report: 0.01 passed the CLI, then the service
        # refused it)
        (["goto", "--to", "z=0.1", "--speed-scale", "0.01"], ("--speed-scale", "[0.05, 1]", "got 0.01")),
        # in the unit the option is given in (kN), not the service's N
        (["work", "settings", "--draft-setpoint-kn", "-20"], ("--draft-setpoint-kn", "(0, 300] kN", "got -20")),
        # a jog without any rate (it used to start a zero-rate jog)
        (["jog", "--duration", "1"], ("--vx", "--vz", "--vroll", "--vpitch")),
    ],
)
def test_non_positive_durations_and_ttls_are_refused_with_the_range(capsys, argv, needles):
    assert main(argv) == 2
    line = _err_line(capsys)
    for n in needles:
        assert n in line


def test_wait_and_detach_are_options_of_every_long_motion_command():
    from bridge.cli.main import build_parser

    p = build_parser()
    for argv in (["goto", "--to", "z=0.1"], ["preset", "go", "work"], ["maneuver", "run", "headland"]):
        a = p.parse_args([*argv, "--wait", "--detach"])
        assert a.wait and a.detach
        a = p.parse_args(argv)
        assert not a.wait and not a.detach


def test_a_service_that_is_down_says_to_start_hitch_serve_and_names_the_endpoint(capsys):
    ep = f"tcp/127.0.0.1:{free_port()}"
    assert main(["stop", "--connect", ep, "--timeout", "1"]) == 2
    line = _err_line(capsys)
    assert "`hitch serve`" in line and ep in line and ".rs:" not in line


def test_motion_commands_send_the_deadline_given_and_refuse_one_out_of_range(monkeypatch, capsys):
    """A security engineer's report: the CLI had no way to set deadline_ms (every command took the default)."""
    calls: list = []

    class Client(_FakeClient):
        def request(self, key, payload=None, **kw):
            calls.append((key, payload))
            return {"motion_id": 3, "maneuver_id": 3, "duration": 1.0, "speed_factor": 1.0, "goal": {}}

        def goto(self, goal, speed_scale=1.0, *, deadline_ms=None):
            calls.append(("goto", deadline_ms))
            return {"motion_id": 3, "duration": 1.0, "speed_factor": 1.0, "goal": dict(goal)}

    monkeypatch.setattr(cli_service, "_client", lambda args: Client())
    assert main(["goto", "--to", "z=0.2", "--deadline-ms", "2500"]) == 0
    assert main(["preset", "go", "far", "--deadline-ms", "60000"]) == 0
    assert main(["maneuver", "run", "m", "--deadline-ms", "1"]) == 0
    assert main(["goto", "--to", "z=0.2"]) == 0  # none given: the service's default
    assert main(["maneuver", "resume", "--deadline-ms", "300"]) == 0
    assert main(["maneuver", "skip"]) == 0
    assert calls == [
        ("goto", 2500),
        ("presets/go", {"name": "far", "deadline_ms": 60000}),
        ("maneuvers/run", {"name": "m", "deadline_ms": 1}),
        ("goto", None),
        ("maneuvers/resume", {"deadline_ms": 300}),
        ("maneuvers/skip", {}),
    ]
    capsys.readouterr()
    for bad in ("0", "60001", "1.5", "soon"):
        assert main(["goto", "--to", "z=0.2", "--deadline-ms", bad]) == 2
        err = capsys.readouterr().err
        assert "--deadline-ms must" in err and "[1, 60000]" in err, err


def test_faults_ack_uses_the_client_method_or_the_faults_ack_key(monkeypatch, capsys):
    calls: list = []

    class Bare(_FakeClient):  # a client without ack_faults: the generic request on faults/ack
        def request(self, key, payload=None, **kw):
            calls.append((key, payload))
            return {"cleared": ["stale_measurement"]}

    class WithAck(Bare):
        def ack_faults(self):
            calls.append(("ack_faults",))
            return {"cleared": []}

    for cls in (Bare, WithAck):
        monkeypatch.setattr(cli_service, "_client", lambda args, cls=cls: cls())
        assert main(["faults", "ack"]) == 0
    assert calls == [("faults/ack", {}), ("ack_faults",)]
    out = capsys.readouterr().out
    assert "faults acknowledged" in out and "stale_measurement" in out
    # the service's reply in words, not Python lists (a new user's report: "(acknowledged: [], faults: [])")
    for reply, words in (
        ({"acknowledged": [], "faults": []}, "faults acknowledged (nothing latched to clear; no fault held)"),
        (
            {"acknowledged": ["references_lost"], "faults": ["ecu_heartbeat"]},
            "faults acknowledged (cleared references_lost; still held: ecu_heartbeat)",
        ),
    ):
        monkeypatch.setattr(WithAck, "ack_faults", lambda self, reply=reply: reply)
        monkeypatch.setattr(cli_service, "_client", lambda args: WithAck())
        assert main(["faults", "ack"]) == 0
        assert capsys.readouterr().out.strip() == words


# ---------------------------------------------------------------------------------------- black box
def test_hitch_log_prints_the_records_verbatim(tmp_path, capsys):
    log = EventLog(event_log_path(tmp_path))
    log.on_request("presets/save", "viewer1", b'{"name": "w"}', False, {"error": "forbidden", "message": "[b]no[/b]"})
    log.on_event({"t": 1.0, "event": "fault", "fault": "stale_measurement", "message": "workspace:x:max"})
    log.close()
    assert main(["log", "--data-dir", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2
    assert "request presets/save by viewer1" in lines[0] and "REFUSED forbidden: [b]no[/b]" in lines[0]
    assert "event fault" in lines[1] and "workspace:x:max" in lines[1]
    assert main(["log", "--data-dir", str(tmp_path), "--json", "--last", "1"]) == 0
    (only,) = capsys.readouterr().out.splitlines()
    assert json.loads(only)["fault"] == "stale_measurement"


def test_hitch_log_shows_the_kind_of_each_motion(tmp_path, capsys):
    """The black box keeps an event's motion kind (``event_kind``); ``hitch log`` shows it on the event's line."""
    log = EventLog(event_log_path(tmp_path))
    log.on_event({"t": 1.0, "seq": 1, "event": "motion_started", "motion_id": 3, "kind": "stop"})
    log.close()
    assert main(["log", "--data-dir", str(tmp_path)]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    assert line.endswith("event motion_started: motion_id=3, event_kind=stop, event_seq=1"), line


def test_hitch_log_prints_a_gap_as_its_sentence(tmp_path, capsys):
    """The black box's gap and suppressed records carry a sentence; hitch log printed every field as key=value."""
    log = EventLog(event_log_path(tmp_path))
    log.on_event({"seq": 1, "event": "mode_changed", "mode": "manual"})
    log.on_event({"seq": 4, "event": "mode_changed", "mode": "auto"})  # 2 and 3 never arrived
    log.close()
    assert main(["log", "--data-dir", str(tmp_path)]) == 0
    gap = next(line for line in capsys.readouterr().out.splitlines() if " gap: " in line)
    assert gap.endswith(
        "gap: 2 event(s) of the service (numbers 2..3) were not recorded: published before the "
        "black box was attached, or lost on the way to it"
    ), gap
    assert "first_event_seq=" not in gap


def test_hitch_log_without_a_log_says_where_it_looked(tmp_path, capsys, monkeypatch):
    assert main(["log", "--data-dir", str(tmp_path)]) == 0
    assert "no event log" in capsys.readouterr().out
    # --follow waits for the log to appear, and says so (a new user's report: it waited with no output)
    import bridge.service.blackbox as blackbox

    def follow(path, **kw):
        raise KeyboardInterrupt  # Ctrl-C at once

    monkeypatch.setattr(blackbox, "follow_events", follow)
    assert main(["log", "--data-dir", str(tmp_path), "--follow"]) == 0
    err = capsys.readouterr().err
    assert "no event log at" in err and "waiting for `hitch serve`" in err, err


def test_hitch_log_follow_prints_what_is_written_after_it_started_and_ends_on_ctrl_c(tmp_path):
    """End to end, the CLI in its own process: it waits for a log that is not there yet (and says so on
    stderr), prints each record the service's writer appends as it is written (one JSON line each, in
    order), and Ctrl-C ends it with status 0."""
    import queue
    import signal
    import subprocess
    import sys
    import threading

    from tests.integration.service_process import ROOT

    proc = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", "log", "--data-dir", str(tmp_path), "--follow", "--json"],
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: queue.Queue[tuple[str, str]] = queue.Queue()
    for name, stream in (("out", proc.stdout), ("err", proc.stderr)):
        threading.Thread(target=lambda n=name, s=stream: [lines.put((n, ln)) for ln in s], daemon=True).start()

    def next_line(stream: str, timeout_s: float = 30.0) -> str:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            try:
                n, ln = lines.get(timeout=max(0.0, end - time.monotonic()))
            except queue.Empty:
                break
            if n == stream:
                return ln
        raise AssertionError(f"no line on std{stream} within {timeout_s} s")

    try:
        assert "waiting for `hitch serve`" in next_line("err")
        log = EventLog(event_log_path(tmp_path))
        try:
            log.on_event({"t": 1.0, "event": "motion_started", "motion_id": 7})
            assert json.loads(next_line("out"))["motion_id"] == 7
            log.on_request("goto", "op1", b'{"goal": {"z": 0.2}}', False, {"error": "busy", "message": "late"})
            rec = json.loads(next_line("out"))
            assert rec["key"] == "goto" and rec["user"] == "op1" and rec["accepted"] is False, rec
        finally:
            log.close()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=15) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_hitch_replay_prints_decoded_frames_poses_and_faults(tmp_path, capsys):
    import can
    import numpy as np

    from bridge.isobus.codec import load_codec
    from bridge.isobus.messages import PositionMeasurement, RearHitchStatus
    from planner.model.kinematics import HitchModel
    from planner.model.sensors import SensorScaling

    model = HitchModel.from_profile("thesis-t132")
    scale = SensorScaling(model.profile)
    c = np.rint(scale.counts_min + (model.neutral - scale.si_min) / scale.resolution).astype(int)  # neutral
    fraction = (c[0] - scale.counts_min[0]) / (scale.counts_max[0] - scale.counts_min[0])
    meas = PositionMeasurement(int(c[1]), int(c[2]), int(c[4]), int(c[3]), 0)
    codec = load_codec()
    path = tmp_path / "bus.asc"
    with can.ASCWriter(str(path)) as w:
        for k, p in enumerate([RearHitchStatus(position=float(fraction)), meas] * 2):
            m = codec.encode(p, source=169)
            m.timestamp = 100.0 + 0.05 * k
            w.on_message_received(m)
        m = codec.encode(meas, source=169)
        m.timestamp = 101.0  # after a silence
        w.on_message_received(m)
    assert main(["replay", str(path)]) == 0
    out = capsys.readouterr().out
    assert "PositionMeasurement from 169" in out and "-> pose x=" in out
    assert "FAULT" in out and "5 frames" in out
    assert main(["replay", str(tmp_path / "missing.asc")]) == 2
    assert "does not exist" in _err_line(capsys)


def test_hitch_replay_of_a_file_with_no_frame_is_an_error_not_0_frames(tmp_path, capsys):
    """A text file that is no CAN log: python-can's .asc reader skips every line it cannot parse, and
    `hitch replay` said "0 frames: none" and exited 0, as if an empty bus had been replayed."""
    import can

    for name, text in [("notes.asc", "shopping list\nmilk\n"), ("empty.asc", "")]:
        path = tmp_path / name
        path.write_text(text, encoding="utf-8")
        assert main(["replay", str(path)]) == 2
        err = _err_line(capsys)
        assert f"CAN log {path} ({len(text)} bytes): no CAN frame in it" in err, err
        assert f"not a {path.suffix} log" in err, err
    empty = tmp_path / "quiet.asc"  # a recording of a silent bus: its header only, still no frame to replay
    can.ASCWriter(str(empty)).stop()
    assert main(["replay", str(empty)]) == 2
    assert "a recording of a bus with no traffic" in _err_line(capsys)


def test_hitch_log_of_a_data_dir_that_does_not_exist_is_an_error(tmp_path, capsys):
    """A typo'd --data-dir printed "(no event log at …)" and exited 0, as for a service that has logged nothing."""
    missing = tmp_path / "nope"
    for extra in ([], ["--follow"]):
        assert main(["log", "--data-dir", str(missing), *extra]) == 2
        err = _err_line(capsys)
        assert f"--data-dir {missing}: no such folder" in err, err


def test_hitch_replay_prints_each_message_at_most_once_an_interval_and_only_the_named_ones(tmp_path, capsys):
    """One second of a bus at rest: the slope sensor and the ECU at 100 Hz. Before, every slope frame
    was printed (100 lines a second, burying the measurements); now each message once per --interval
    (0.1 s) per sender, and --only picks messages by name (an unknown name is refused, naming the allowed)."""
    import can

    from bridge.isobus.codec import load_codec
    from bridge.isobus.messages import FigureOfMerit, SlopeSensorInformation

    codec = load_codec()
    ok = FigureOfMerit.FULLY_FUNCTIONAL
    ssi = SlopeSensorInformation(0.01, 0.02, 0.0, pitch_merit=ok, roll_merit=ok, pitch_rate_merit=ok)
    path = tmp_path / "bus.asc"
    with can.ASCWriter(str(path)) as w:
        for k in range(100):
            m = codec.encode(ssi, source=226)
            m.timestamp = 100.0 + 0.01 * k
            w.on_message_received(m)
    assert main(["replay", str(path)]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "SlopeSensorInformation from" in ln]
    assert 9 <= len(lines) <= 11, len(lines)
    assert main(["replay", str(path), "--all"]) == 0
    assert capsys.readouterr().out.count("SlopeSensorInformation from") == 100
    assert main(["replay", str(path), "--only", "PositionMeasurement"]) == 0
    out = capsys.readouterr().out
    assert "SlopeSensorInformation from" not in out and "100 frames" in out
    assert main(["replay", str(path), "--only", "Slope"]) == 2
    err = capsys.readouterr().err
    assert "unknown message Slope" in err and "SlopeSensorInformation" in err


# ---------------------------------------------------------------------------------------- plan
def test_plan_shows_the_final_approach_of_a_profile_that_asks_for_one(tmp_path, capsys):
    prof = profile_file_with_final_approach(tmp_path)
    # from neutral down to z − 50 mm: the goto dips 4 mm below the goal in z and rises to it
    argv = ["plan", "--profile", str(prof), "--to", "z=0.05", "--json"]
    assert main(argv) == 0
    fa = json.loads(capsys.readouterr().out)["final_approach"]
    assert fa["via"][1] == pytest.approx(0.05 - 0.004) and fa["short"] == []
    assert main(argv[:-1]) == 0
    assert "final approach via: x=" in capsys.readouterr().out
    assert main(["plan", "--to", "z=0.05", "--json"]) == 0  # the built-in profile: no final approach
    assert json.loads(capsys.readouterr().out)["final_approach"] is None


def test_plan_shows_where_a_profile_with_a_lag_aims_the_mechanism(tmp_path, capsys):
    prof = profile_file_with_final_approach(tmp_path)
    prof.write_text(
        prof.read_text() + 'side = "above"\nlag = { x = 0.0005, z = 0.0006, roll = 0.001, pitch = 0.002 }\n'
    )
    argv = ["plan", "--profile", str(prof), "--to", "z=0.15", "--json"]  # up from neutral (z 0.114)
    assert main(argv) == 0
    fa = json.loads(capsys.readouterr().out)["final_approach"]
    assert fa["aim"][1] == pytest.approx(0.15 - 0.0006)  # ending from above: the implement rests 0.6 mm higher
    assert fa["via"][1] == pytest.approx(0.15 - 0.0006 + 0.004)  # the via above the aim: the move ends falling
    assert main(argv[:-1]) == 0
    out = capsys.readouterr().out
    assert "mechanism aimed at: x=" in out and "z=+0.1494" in out and "cut at" not in out
    # ending from above, the aim lies below the goal: at the lower face it is cut, and that is said
    assert main(["plan", "--profile", str(prof), "--to", "pitch=-0.1"]) == 0
    assert "cut at the workspace face or the upper height in pitch" in capsys.readouterr().out


def test_profile_show_says_the_final_approach_its_lag_and_the_count_approach(tmp_path, capsys):
    """A new user's report: `hitch profile show` left out [motion], so a profile's final approach, its lag and
    its count approach could not be checked with it."""
    prof = profile_file_with_final_approach(tmp_path, count_approach=True)
    prof.write_text(
        prof.read_text() + "\n[motion.final_approach.lag]\nx = 0.0005\nz = 0.0006\nroll = 0.001\npitch = 0.002\n"
    )
    assert main(["profile", "show", "--profile", str(prof)]) == 0
    out = capsys.readouterr().out
    assert "final approach: from below, offsets x=+2.500 mm" in out and "lag of the pin play: x=+0.500 mm" in out
    assert "count approach: on" in out
    assert main(["profile", "show", "--profile", str(prof), "--json"]) == 0
    motion = json.loads(capsys.readouterr().out)["motion"]
    assert motion["final_approach"]["lag"] == {"x": 0.0005, "z": 0.0006, "roll": 0.001, "pitch": 0.002}
    assert main(["profile", "show"]) == 0
    out = capsys.readouterr().out
    assert "final approach: off" in out and "count approach: off" in out


def test_plan_shows_the_count_approach_a_goto_ends_with(tmp_path, capsys, monkeypatch):
    """With ``motion.count_approach`` a goto lasts 1.2 s longer than its plan: `hitch plan` says so, and which
    counts it streams (it gave the plan's duration alone)."""
    prof = profile_file_with_final_approach(tmp_path)
    stops = "{ lift = [0.19, 0.31], tilt = [-0.09], top = [-0.12], left = [-0.11], right = [-0.11] }"
    above = "{ lift = [-0.2, -0.31], tilt = [0.08], top = [0.12], left = [0.06], right = [0.11] }"
    prof.write_text(
        prof.read_text(encoding="utf-8")
        + f"\n[motion.count_approach]\nfrom_below_counts = {stops}\nfrom_above_counts = {above}\n",
        encoding="utf-8",
    )
    argv = ["plan", "--profile", str(prof), "--to", "z=0.05,pitch=0.02", "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    ca = out["count_approach"]
    assert ca["duration_s"] == pytest.approx(1.2)
    final, via = np.array(ca["final_counts"]), np.array(ca["via_counts"])
    assert np.all(np.abs(final - via) >= 1) and np.all(np.abs(final - via) <= 2)  # a back-off of 1 or 2 counts
    model = HitchModel(load_profile(prof))
    goal = np.array([0.0, 0.05, 0.0, 0.02])
    exact = SensorScaling(model.profile).counts_of(ExactInverse(model).solve(goal)[0])
    assert np.all(np.abs(final - exact) <= 1.0)  # on a count next to the goal's
    assert main(argv[:-1]) == 0
    assert "count approach after the plan: +1.20 s (a goto lasts" in capsys.readouterr().out
    # a goal where the approach's counts are not admissible (plan_count_tail gives none): said, not silent
    monkeypatch.setattr("bridge.cli.plan.plan_count_tail", lambda *a, **k: None)
    assert main(argv[:-1]) == 0
    assert "count approach: none at this goal" in capsys.readouterr().out
    monkeypatch.undo()
    assert main(["plan", "--to", "z=0.05", "--json"]) == 0  # the built-in profile: none
    assert json.loads(capsys.readouterr().out)["count_approach"] is None


def test_faults_list_prints_each_held_fault_with_its_kind_and_reason(monkeypatch, capsys):
    """A new user's report: `hitch faults` only offered `ack`; nothing listed what is held."""
    ecu = {
        "online": True,
        "faults": ["ecu_heartbeat", "references_lost"],
        "fault_reasons": ["ECU heartbeat timeout", "the ECU reports its watchdog expired [after 0.2 s]"],
        "ack_required": ["references_lost"],
        "link_faults": ["references_lost"],
    }

    class Client(_FakeClient):
        def state(self):
            return {"seq": 1, "ecu": ecu}

    monkeypatch.setattr(cli_service, "_client", lambda args: Client())
    assert main(["faults", "list"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines == [
        "ecu_heartbeat (self-clearing): ECU heartbeat timeout",
        "references_lost (latching: `hitch faults ack` once its cause is gone): "
        "the ECU reports its watchdog expired [after 0.2 s]",
    ]
    assert main(["faults", "list", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {
        k: ecu[k] for k in ("faults", "fault_reasons", "ack_required", "link_faults")
    }
    ecu.update(faults=[], fault_reasons=[], ack_required=[], link_faults=[])
    assert main(["faults", "list"]) == 0
    assert capsys.readouterr().out.strip() == "no fault held"


def test_signed_never_prints_a_negative_zero():
    from bridge.cli.output import signed

    assert signed(-0.0, 5) == "+0.00000" and signed(-4e-7, 5) == "+0.00000" and signed(-6e-6, 5) == "-0.00001"
    assert signed(0.1234, 4) == "+0.1234" and signed(2, 2) == "+2.00"
    assert signed(-1.5, 1) == "-1.5"


@pytest.mark.parametrize("outcome", ["motion_finished", "motion_aborted"])
def test_an_awaited_motion_says_how_it_ended_and_an_aborted_one_exits_1(monkeypatch, capsys, outcome):
    """A new user's report: `goto --wait` printed "accepted …; now at …" and exited 0 when a stop or a link
    fault had aborted the motion (`maneuver run --wait` said so and exited 1)."""
    pose = {"x": 0.0, "z": 0.0970, "roll": 0.0, "pitch": 0.0, "y": 0.0, "yaw": 0.0}

    class Client(_FakeClient):
        def __init__(self):
            self.listeners: dict = {}

        def goto(self, to, speed_scale=None):
            return {"motion_id": 9, "duration": 15.53, "speed_factor": 1.0}

        def request(self, key, payload=None, **kw):
            assert key == "presets/go"
            return {"motion_id": 9, "duration": 2.0}

        def subscribe(self, key, cb):
            self.listeners[key] = cb

        def wait_motion(self, motion_id, *, timeout_s):
            e = {"event": outcome, "motion_id": motion_id, "seq": 7}
            if outcome == "motion_aborted":
                e["reason"] = "stop requested"
            self.listeners["events"](e)
            return {"motion_id": 10, "moving": False, "pose": pose}

    monkeypatch.setattr(cli_service, "_client", lambda args: Client())
    expected = 1 if outcome == "motion_aborted" else 0
    for argv in (["goto", "--to", "z=-0.15", "--wait"], ["preset", "go", "work", "--wait"]):
        assert main(argv) == expected
        out = capsys.readouterr().out
        assert "now at" in out and "z=+0.0970" in out
        assert ("ABORTED: stop requested" in out) == (outcome == "motion_aborted"), out
        assert ("; finished; now at" in out) == (outcome == "motion_finished"), out  # it said only "accepted" before
    assert main(["goto", "--to", "z=-0.15", "--wait", "--json"]) == expected
    final = json.loads(capsys.readouterr().out)["final"]
    assert final["outcome"]["event"] == outcome


def test_implement_list_says_when_none_is_selected(monkeypatch, capsys):
    """A new user's report: `implements/list` said selected 'default', which no line of the list showed."""
    import bridge.cli.implements as cli_implements

    class Client(_FakeClient):
        def request(self, key, payload=None, **kw):
            assert key == "implements/list"
            return {"implements": [], "selected": "default"}

    monkeypatch.setattr(cli_implements, "_client", lambda args: Client(), raising=False)
    monkeypatch.setattr(cli_service, "_client", lambda args: Client())
    assert main(["implement", "list"]) == 0
    assert "selected: none ('default': the hitch without an implement's data)" in capsys.readouterr().out


def test_config_prints_no_python_none_for_a_service_without_an_implement(monkeypatch, capsys):
    """A new user's report: `hitch config` printed `implement: None`; `fleet ls` prints `-` for the same reply."""

    class Client(_FakeClient):
        def config(self):
            return {"prefix": "hitch", "profile": "thesis-t132", "category": "2", "implement": None, "mode": "auto"}

    monkeypatch.setattr(cli_service, "_client", lambda args: Client())
    assert main(["config"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "implement: -" in lines
    assert not any("None" in line for line in lines), lines


def test_config_prints_the_workspace_strokes_and_jog_rates_with_units(monkeypatch, capsys):
    """An operator's trial: ``hitch config`` printed no limit or workspace though its help says "profile, limits,
    workspace, mode". Truth: the limits of a real config reply (``service_info``'s), printed in mm / mrad."""
    limits = {
        "workspace": {"x": [-0.06, 0.06], "z": [-0.21627, 0.311729], "roll": [-0.058, 0.058], "pitch": [-0.1, 0.058]},
        "strokes": {"lift": [-0.223, 0.7], "tilt": [0.58, 0.73]},
        "jog_velocity": {"x": 0.02713267, "z": 0.0465232, "roll": 0.01335401, "pitch": 0.02542145},
    }

    class Client(_FakeClient):
        def config(self):
            return {"prefix": "hitch", "profile": "thesis-t132", "mode": "auto", "limits": limits}

    monkeypatch.setattr(cli_service, "_client", lambda args: Client())
    assert main(["config"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert (
        "workspace: x [-60.0, 60.0] mm, z [-216.3, 311.7] mm, roll [-58.0, 58.0] mrad, pitch [-100.0, 58.0] mrad"
        in (lines)
    ), lines
    assert "strokes: lift [-223.0, 700.0] mrad, tilt [580.0, 730.0] mm" in lines, lines
    assert "jog top rates: x 27.1 mm/s, z 46.5 mm/s, roll 13.4 mrad/s, pitch 25.4 mrad/s" in lines, lines


def test_jog_help_names_jog_velocity_as_a_field_of_the_config_reply_not_a_setting(capsys):
    """A new user's report: the help called limits.jog_velocity "its config key", but a service config file with
    [limits] is refused; it is a field of the `config` reply, from the profile's actuator speeds."""
    with pytest.raises(SystemExit):
        main(["jog", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "config key" not in text
    assert "not a service setting" in text and "`hitch config --json` shows it as limits.jog_velocity" in text


def test_hitch_log_picks_records_by_kind_key_and_time(tmp_path, capsys):
    """A service engineer reading an incident: the log printed everything, without a way to pick the faults, one
    key's requests or the last ten minutes."""
    path = event_log_path(tmp_path)
    log = EventLog(path)
    log.on_event({"seq": 1, "event": "mode_changed", "mode": "manual"})
    log.on_request("goto", "olga", b'{"goal": {"z": 0.1}}', True, {"accepted": True, "motion_id": 4})
    log.on_request("presets/save", "olga", b'{"name": "a"}', False, {"error": "bad_request", "message": "no"})
    log.on_event({"seq": 2, "event": "fault", "faults": ["ecu_heartbeat"], "message": "ECU heartbeat timeout"})
    log.close()
    recs = [r for r in read_events(path) if r["kind"] in ("request", "event")]
    old = recs[0]["t"]

    def shown(*argv: str) -> list[str]:
        assert main(["log", "--data-dir", str(tmp_path), "--json", *argv]) == 0
        return [
            json.loads(line).get("key") or json.loads(line).get("event")
            for line in capsys.readouterr().out.splitlines()
        ]

    assert shown("--kind", "event") == ["mode_changed", "fault"]
    assert shown("--key", "goto,fault") == ["goto", "fault"]
    assert shown("--kind", "request", "--key", "presets/save") == ["presets/save"]
    assert (
        "mode_changed" in shown("--since", "1h")
        and shown("--since", time.strftime("%Y-%m-%d %H:%M", time.localtime(old + 120))) == []
    )
    assert main(["log", "--data-dir", str(tmp_path), "--key", "jog"]) == 0
    assert "matches --kind / --key / --since" in capsys.readouterr().out
    empty = tmp_path / "empty"  # a log with no record, no filter: no word about filters (a review)
    event_log_path(empty).parent.mkdir(parents=True)
    event_log_path(empty).write_text("")
    assert main(["log", "--data-dir", str(empty)]) == 0
    assert "matches" not in capsys.readouterr().out
    assert main(["log", "--data-dir", str(tmp_path), "--kind", "requests"]) == 2
    assert "--kind: unknown kind requests; allowed: request, event" in _err_line(capsys)
    assert main(["log", "--data-dir", str(tmp_path), "--since", "yesterday"]) == 2
    assert "--since: 'yesterday': a duration ago (90s, 10m, 2h, 1d) or a local time" in _err_line(capsys)


def _replay_log(tmp_path, name: str = "bus.asc"):
    """2.5 s of the cylinder ECU (169): 0xFF22 (system state 3: controllers on, watchdog tripped) and its lift
    at 100 Hz, its heartbeat at 10 Hz; measurements silent 0.5–1.0 s and again 1.5–2.0 s (stale twice)."""
    import can

    from bridge.isobus.codec import load_codec
    from bridge.isobus.messages import Heartbeat, PositionMeasurement, RearHitchStatus

    model = HitchModel.from_profile("thesis-t132")
    scale = SensorScaling(model.profile)
    c = np.rint(scale.counts_min + (model.neutral - scale.si_min) / scale.resolution).astype(int)
    fraction = float((c[0] - scale.counts_min[0]) / (scale.counts_max[0] - scale.counts_min[0]))
    meas = PositionMeasurement(int(c[1]), int(c[2]), int(c[4]), int(c[3]), 3)
    codec = load_codec()
    t0 = 1_765_000_000.0
    path = tmp_path / name
    with can.ASCWriter(str(path)) as w:
        for k in range(250):
            t = 0.01 * k
            out = [] if 0.5 <= t < 1.0 or 1.5 <= t < 2.0 else [meas, RearHitchStatus(position=fraction)]
            out += [Heartbeat(k // 10)] if k % 10 == 0 else []
            for p in out:
                m = codec.encode(p, source=169)
                m.timestamp = t0 + t
                w.on_message_received(m)
    return path, t0


def test_hitch_replay_prints_every_fault_raise_and_clear_and_counts_both(tmp_path, capsys):
    """The stale measurement came twice; replay said it once ("1 faults raised") and never that it cleared."""
    path, _ = _replay_log(tmp_path)
    assert main(["replay", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.count("FAULT stale_measurement") == 2 and out.count("CLEARED stale_measurement") == 2, out
    assert out.rstrip().endswith("2 faults raised, 2 cleared"), out


def test_hitch_replay_prints_the_logs_start_in_local_time_and_with_clock_each_lines(tmp_path, capsys):
    """Replay gave only seconds from the first frame: nothing to line it up with `hitch log` (local time)."""
    path, t0 = _replay_log(tmp_path)
    day = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t0))
    assert main(["replay", str(path)]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first == f"log starts {day}.000 ({t0:.6f})", first
    assert main(["replay", str(path), "--clock", "--only", "Heartbeat", "--interval", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    beats = [ln for ln in lines if "Heartbeat from 169" in ln]
    assert [ln.split()[0] for ln in beats] == [
        time.strftime("%H:%M:%S", time.localtime(t0 + s)) + ".000" for s in (0, 1, 2)
    ]
    stale = next(ln for ln in lines if "FAULT stale_measurement" in ln)
    t_s = float(stale.split()[1])
    assert stale.split()[0] == time.strftime("%H:%M:%S", time.localtime(t0 + t_s)) + f".{round(t_s * 1000) % 1000:03d}"


def test_hitch_replay_json_applies_only_and_interval_and_names_enums(tmp_path, capsys):
    """`--json --only Heartbeat` printed every record of the log; now --only and --interval pick the JSON
    records as they pick the text lines (faults always), each with its Unix time, the system state in words."""
    path, t0 = _replay_log(tmp_path)
    assert main(["replay", str(path), "--json", "--only", "Heartbeat", "--interval", "1"]) == 0
    recs = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    frames = [r for r in recs if r["source"] is not None]
    assert [r["message"] for r in frames] == ["Heartbeat"] * 3, frames
    assert [r["timestamp"] for r in frames] == [pytest.approx(t0 + s, abs=1e-5) for s in (0, 1, 2)]
    assert [r["message"] for r in recs if r["source"] is None] == ["fault", "fault_cleared"] * 2
    assert main(["replay", str(path), "--json", "--only", "PositionMeasurement", "--interval", "1"]) == 0
    recs = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    ff22 = [r for r in recs if r["message"] == "PositionMeasurement"]
    assert len(ff22) == 3 and "watchdog tripped" in ff22[0]["system_state"], ff22


def test_hitch_replay_prints_the_ecus_system_state_by_name(tmp_path, capsys):
    """`system_state=3` was printed raw, though its bits have names (bridge.isobus.system_state)."""
    path, _ = _replay_log(tmp_path)
    assert main(["replay", str(path), "--only", "PositionMeasurement", "--interval", "5"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "PositionMeasurement from 169" in ln)
    assert "system_state=3 (controllers on, watchdog tripped; restart count 0)" in line, line


class _VirtualTime:
    """time.monotonic / time.sleep on a clock that moves only when slept or told to."""

    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.now += max(0.0, s)


def test_a_held_jog_is_refreshed_on_a_fixed_grid_and_a_late_refresh_does_not_shift_the_rest(monkeypatch):
    """A new engineer's trial: the CLI slept 100 ms after each reply, so every period grew by the reply's time and
    one reply late under load (297 ms) split the jog in two."""
    clock = _VirtualTime()
    monkeypatch.setattr(cli_service, "time", clock)
    calls: list[float] = []

    def refresh() -> dict:
        calls.append(clock.now)
        clock.now += 0.3 if len(calls) == 3 else 0.01  # each reply takes 10 ms, the third 300 ms
        return {"motion_id": 1}

    cli_service._refresh_until(refresh, {}, 1.0, 0.1)
    gaps = np.diff(calls)
    assert np.allclose(gaps[:2], 0.1) and abs(gaps[2] - 0.3) < 1e-9, gaps  # on the grid; after the late one at once
    assert np.allclose(gaps[3:], 0.1), gaps
    assert calls[-1] == pytest.approx(1.0)  # the last at the end: held until ttl after it, as asked (a review)


def test_a_jog_that_lapsed_between_refreshes_says_so_and_names_its_motions(monkeypatch, capsys):
    import contextlib

    clock = _VirtualTime()
    monkeypatch.setattr(cli_service, "time", clock)
    replies = iter([1, 1, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2])

    class Client:
        def jog(self, *a):
            clock.now += 0.01
            return {"motion_id": next(replies), "limited": {}}

    monkeypatch.setattr(cli_service, "_client", lambda args: contextlib.nullcontext(Client()))
    assert main(["jog", "--vz", "0.05", "--duration", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "jog motions 1, 2: it lapsed 1 time(s)" in out and "ttl 200 ms" in out, out


def test_a_jog_the_guard_refuses_says_so_and_exits_1(monkeypatch, capsys):
    """A re-run of an operator's trial: a jog the guard refused printed "jog motion 95, limited: …" and exited 0
    (the reply's "accepted": true: the motion exists and holds the hitch)."""
    import contextlib

    reply = {
        "accepted": True,
        "motion_id": 95,
        "guard": "refused",
        "speed_factor": 0.0,
        "limited": {"esm": "hard: esm would be 76.21 J (threshold 2000 J) at t = 1.00 s"},
    }

    class Client:
        def jog(self, *a):
            return dict(reply)

    monkeypatch.setattr(cli_service, "_client", lambda args: contextlib.nullcontext(Client()))
    assert main(["jog", "--vz", "0.02"]) == 1
    out = capsys.readouterr().out
    assert out.startswith("jog refused by the guard at its last refresh (motion 95 holds the hitch): esm by hard"), out


def test_a_state_with_the_ecu_offline_shows_how_old_its_pose_is(capsys):
    """An operator's trial: 3.5 s after the ECU fell silent ``hitch state`` printed ``auto at rest … z=+0.1074 m
    … ECU OFFLINE`` with no age: an old pose read as live."""
    args = argparse.Namespace(json=False)
    ecu = {"online": False, "faults": ["stale_measurement"], "measurement_age_s": 3.52}
    old = {"seq": 9, "mode": "auto", "moving": False, "motion_id": None, "pose": {"z": 0.1074}, "ecu": ecu}
    cli_service._print(args, old, cli_service._state_line(old), markup=True)
    line = capsys.readouterr().out
    assert "moving or not: unknown (ECU silent)" in line and "z=+0.1074 m (measured 3.5 s ago)" in line, line
    assert "at rest" not in line, line  # the planner's word, not the hitch's (a re-run: it moved on 41 mm)
    live = {**old, "ecu": {"online": True, "measurement_age_s": 0.004}}
    cli_service._print(args, live, cli_service._state_line(live), markup=True)
    line = capsys.readouterr().out
    assert "auto at rest" in line and "ago" not in line, line


def test_state_follow_keeps_following_through_a_silence_after_samples(monkeypatch, capsys):
    """An operator's trial: ``hitch state --follow`` exited 2 with "no h30op/state sample within 5 s — … start one
    with hitch serve" when the service stopped, though it had been receiving samples; it follows on now, saying
    the silence once. A service never heard stays the setup error."""
    from bridge.service.client import ServiceTimeout

    state = {"seq": 1, "mode": "auto", "moving": False, "motion_id": None, "pose": {"z": 0.1}, "ecu": {"online": True}}
    bursts = [[state, {**state, "seq": 2}], [], [], [{**state, "seq": 3}]]  # samples, two silences, samples again

    class Client(_FakeClient):
        def follow(self, what="state", **kw):
            batch = bursts.pop(0)
            yield from batch
            raise ServiceTimeout("no hitch/state sample within 5 s")

    monkeypatch.setattr(cli_service, "_client", lambda args: Client())
    assert main(["state", "--follow", "--count", "3"]) == 0
    captured = capsys.readouterr()
    assert [line.split()[0] for line in captured.out.splitlines()] == ["#1", "#2", "#3"], captured.out
    assert captured.err.count("the service stopped or the link is down; following on") == 1, captured.err

    class Never(_FakeClient):
        def follow(self, what="state", **kw):
            raise ServiceTimeout("no hitch/state sample within 5 s")
            yield {}

    monkeypatch.setattr(cli_service, "_client", lambda args: Never())
    monkeypatch.setattr(cli_service, "_alive", lambda c, timeout_s=1.0: False)
    assert main(["state", "--follow"]) == 2
    assert "start one with `hitch serve`" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("kw", "want"),
    [
        ({}, ["can: virtual hitch (the simulated ECU and tractor)", "ground speed 1.50 m/s (5.4 km/h)", "flat ground"]),
        ({"sim_scenario": "terrain"}, ["simulated tractor: scenario terrain, ground speed"]),
        ({"sim_field": "chisel"}, ["simulated tractor: field chisel, ground speed 2.22 m/s (8.0 km/h)"]),
        ({"simulate_ecu": False}, ["(a real cylinder ECU)"]),
    ],
)
def test_config_says_what_the_simulated_tractor_drives_over(monkeypatch, capsys, kw, want):
    """A field technician's trial: a service started with ``--sim-scenario`` said so only in ``hitch config
    --json``; the plain text named no bus, no scenario and no speed. Truth: the config reply of a real service
    config (``service_info``)."""
    from bridge.service.config import ServiceConfig
    from bridge.service.machine import build_guard, build_model, service_info

    cfg = ServiceConfig(**kw)
    reply = service_info(cfg, build_guard(cfg, build_model(cfg)))

    class Client(_FakeClient):
        def config(self):
            return reply

    monkeypatch.setattr(cli_service, "_client", lambda args: Client())
    assert main(["config"]) == 0
    out = capsys.readouterr().out
    for w in want:
        assert w in out, out
    assert ("simulated tractor" in out) == cfg.simulate_ecu, out


def test_implement_define_says_what_a_redefinition_cleared(monkeypatch, capsys):
    """A newcomer redefined an implement to change its mass: its upper height, lowering speed and headland were
    gone without a word. The CLI says what the service's reply lists as cleared."""
    sent = []

    class Client(_FakeClient):
        def request(self, key, payload=None, **kw):
            sent.append((key, payload))
            return {
                "defined": "plough3",
                "implement": {},
                "selected": "plough3",
                "cleared": ["upper_height_m", "headland"],
            }

    monkeypatch.setattr(cli_service, "_client", lambda args: Client())
    assert main(["implement", "define", "plough3", "--category", "2", "--mass", "1200", "--com", "0,0.7,0.35"]) == 0
    out = capsys.readouterr().out
    assert "defined plough3; cleared upper_height_m, headland (a define replaces the whole record" in out, out
    assert sent[0][0] == "implements/define"


def test_preset_save_prints_the_service_s_note(monkeypatch, capsys):
    """The service's ``note`` (a headland preset the implement's own pose shadows) is printed, not only in --json."""

    class Client(_FakeClient):
        def request(self, key, payload=None, **kw):
            pose = {"x": 0.0, "z": 0.2, "roll": 0.0, "pitch": 0.0}
            return {"saved": "headland", "pose": pose, "implement": "p", "note": "implement 'p' has a headland pose"}

    monkeypatch.setattr(cli_service, "_client", lambda args: Client())
    assert main(["preset", "save", "headland"]) == 0
    assert "note: implement 'p' has a headland pose" in capsys.readouterr().out
