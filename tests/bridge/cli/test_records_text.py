"""``hitch log``'s text output (:mod:`bridge.cli.records`): limits in words, numbers rounded with their units,
and which log it reads said on stderr.

A new user's trial: ``limits={'velocity:tilt': 'speed: velocity:tilt would be 0.5084 (threshold 1)'}``,
``duration=11.673908740014241``, ``timeout=45.0``, and a stranger's run read from the default folder without a
word. Truth: the expected lines are written by hand from the numbers given (19.68001077 s → 19.68 s at 1 ms;
0.0123 m → +12.3 mm; a speed factor 0.5084 → 51 %); the --json output must keep the numbers bit for bit.
"""

from __future__ import annotations

import json

from bridge.cli.main import main
from bridge.cli.records import _fmt_fields, format_record
from bridge.service.blackbox import EventLog, event_log_path

_TILT = "speed: velocity:tilt would be 0.5084 (threshold 1) at t = 0.00 s"


def test_a_limit_reached_event_says_its_limits_in_words():
    rec = {
        "seq": 7,
        "kind": "event",
        "event": "limit_reached",
        "motion_id": 3,
        "limits": {"velocity:tilt": _TILT},
        "event_t": 101.38,
        "event_seq": 12,
    }
    assert format_record(rec) == (
        "- #7 event limit_reached: motion_id=3, limits=[tilt cylinder (right lift rod) at its speed limit: "
        "slowed to 51 % (velocity:tilt)], event_seq=12"
    )


def test_times_are_rounded_to_the_millisecond_and_say_seconds():
    rec = {
        "seq": 8,
        "kind": "event",
        "event": "maneuver_finished",
        "maneuver": "levelling",
        "elapsed": 19.68001077200097,
        "clock": 101.38412,
        "event_seq": 13,
    }
    assert format_record(rec) == (
        "- #8 event maneuver_finished: maneuver=levelling, elapsed=19.68 s, clock=101.384 s, event_seq=13"
    )
    started = {"seq": 9, "kind": "event", "event": "maneuver_started", "steps": 3, "actions": 2, "timeout": 45.0}
    assert format_record(started) == "- #9 event maneuver_started: steps=3, actions=2, timeout=45 s"


def test_a_goal_pose_is_in_mm_and_mrad_and_a_duration_in_s():
    rec = {
        "seq": 10,
        "kind": "event",
        "event": "motion_started",
        "motion_id": 5,
        "duration": 11.673908740014241,
        "goal": {"x": 0.0123, "z": 0.31, "roll": -0.0015, "pitch": 0.0},
        "event_kind": "goto",
    }
    assert format_record(rec) == (
        "- #10 event motion_started: motion_id=5, duration=11.674 s, "
        "goal=(x +12.3 mm, z +310.0 mm, roll -1.5 mrad, pitch +0.0 mrad), event_kind=goto"
    )


def test_fields_named_with_a_unit_carry_it():
    rec = {
        "seq": 11,
        "kind": "event",
        "event": "work_finished",
        "depth_m": 0.123456,
        "draft_n": 12345.6,
        "speed_scale": 0.5,
        "age_s": 0.0004,
        "deadline_ms": 1000,
        "lowering_speed_m_s": 0.05,
        "ratio": 0.333333,
    }
    assert format_record(rec) == (
        "- #11 event work_finished: depth_m=0.1235 m, draft_n=12346 N, speed_scale=50 %, age_s=0 s, "
        "deadline_ms=1000 ms, lowering_speed_m_s=0.05 m/s, ratio=0.3333"
    )
    # a suppressed record without its sentence, and the replay's decoded frames: the same units
    assert format_record({"seq": 2, "kind": "suppressed", "count": 4, "window_s": 29.99987}) == (
        "- #2 suppressed: count=4, window_s=30 s"
    )
    assert _fmt_fields({"x_m": 0.123456, "lift_pa": 1.5e7, "latency_s": 0.0123456, "top": 812}) == (
        "x_m=0.1235 m lift_pa=150 bar latency_s=0.012 s top=812"
    )


def test_json_keeps_the_numbers_exact(tmp_path, capsys):
    log = EventLog(event_log_path(tmp_path))
    log.on_event({"t": 1.0, "event": "maneuver_finished", "elapsed": 19.68001077200097})
    log.close()
    assert main(["log", "--data-dir", str(tmp_path), "--json"]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    assert json.loads(line)["elapsed"] == 19.68001077200097


def _default_log(tmp_path, monkeypatch):
    """A log in the default data dir ($XDG_DATA_HOME/hitch-planner) with one rotated file before it."""
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path))
    path = event_log_path(tmp_path / "hitch-planner")
    path.parent.mkdir(parents=True)
    (path.parent / "events.jsonl.1").write_text('{"seq": 1, "t": 1.0, "kind": "service", "what": "start"}\n')
    path.write_text('{"seq": 2, "t": 2.0, "kind": "service", "what": "stop"}\n')
    return path


def test_hitch_log_says_on_stderr_which_files_of_the_default_folder_it_reads(tmp_path, monkeypatch, capsys):
    path = _default_log(tmp_path, monkeypatch)
    assert main(["log"]) == 0
    cap = capsys.readouterr()
    assert cap.err.splitlines() == [
        f"(reading the event log {path} and 1 rotated file(s) before it (events.jsonl.1) "
        "(the default data dir; --data-dir names another))"
    ]
    assert [line.split(" ", 3)[3] for line in cap.out.splitlines()] == ["service: what=start", "service: what=stop"]
    # --json: stdout only the records, one JSON object a line; the note still on stderr
    assert main(["log", "--json"]) == 0
    cap = capsys.readouterr()
    assert [json.loads(line)["what"] for line in cap.out.splitlines()] == ["start", "stop"]
    assert str(path) in cap.err
    # a folder given: said too, not called the default
    assert main(["log", "--data-dir", str(tmp_path / "hitch-planner"), "--last", "1"]) == 0
    cap = capsys.readouterr()
    assert cap.err.splitlines() == [f"(reading the event log {path} and 1 rotated file(s) before it (events.jsonl.1))"]


def test_hitch_log_json_without_a_log_keeps_stdout_empty(tmp_path, capsys):
    assert main(["log", "--data-dir", str(tmp_path), "--json"]) == 0
    cap = capsys.readouterr()
    assert cap.out == ""
    assert "no event log at" in cap.err


def test_an_event_shows_when_it_happened_and_when_it_was_logged_if_that_was_later():
    """A field trial: after the service was frozen, an abort, service_lost and a finish all showed the time they
    were written (05:52:48.636), not when they happened (the abort at 05:52:47.684)."""
    import time

    happened = time.mktime((2026, 12, 7, 5, 52, 47, 0, 0, -1)) + 0.684
    late = format_record(
        {"t": happened + 0.9525, "seq": 9, "kind": "event", "event": "motion_aborted", "event_t": happened}
    )
    assert late.startswith("2026-12-07 05:52:47.684 #9 (logged 05:52:48.636) event motion_aborted"), late
    prompt = format_record({"t": happened + 0.002, "seq": 10, "kind": "event", "event": "x", "event_t": happened})
    assert prompt.startswith("2026-12-07 05:52:47.684 #10 event x"), prompt  # logged at once: one time
    assert format_record({"t": happened, "seq": 11, "kind": "event", "event": "y"}).startswith(
        "2026-12-07 05:52:47.684 #11 event y"
    )
