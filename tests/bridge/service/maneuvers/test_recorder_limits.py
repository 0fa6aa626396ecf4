"""Teach-in (bridge.service.maneuvers.recorder) at its limits: a command accepted while the recording is
full still succeeds (the step is dropped, counted and named in the script's description), a pause longer
than one ``wait`` / ``wait_for distance`` step allows is recorded as several steps (the script handed out
parses), and concurrent callers (a jog inline, a goto from the motion lane) lose no step."""

from __future__ import annotations

import threading

import pytest

from bridge.service.maneuvers.language import MAX_STEPS, parse_maneuver
from bridge.service.maneuvers.recorder import ManeuverRecorder
from tests.helpers import SimService

POSE = {"x": 0.0, "z": 0.1, "roll": 0.0, "pitch": 0.0}


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _recorder(clock: _Clock, odometer: list[float] | None = None) -> ManeuverRecorder:
    return ManeuverRecorder(clock, lambda: dict(POSE), (lambda: None) if odometer is None else (lambda: odometer[0]))


def test_a_goto_accepted_while_the_recording_is_full_succeeds_and_the_script_says_what_was_dropped(model, tmp_path):
    svc = SimService(model, tmp_path / "hitch.sqlite3")
    try:
        assert svc.call("maneuvers/record/start")[0]
        svc.api.recorder.steps.extend({"wait": 1.0} for _ in range(MAX_STEPS))  # a full recording
        ok, r = svc.call("goto", {"goal": {"z": 0.2}})
        assert ok, r  # the hitch moves: the reply must say so (it was an error before)
        assert svc.mc.current_state() is not None and r["accepted"] is True
        ok, r = svc.call("maneuvers/record/stop", {"name": "taught"})
        assert ok, r
        script = parse_maneuver(r["script"])
        assert len(script.steps) == MAX_STEPS
        assert "dropped" in script.description and str(MAX_STEPS) in script.description
    finally:
        svc.close()


def test_a_pause_beyond_one_wait_step_is_recorded_as_several_and_parses():
    clock = _Clock()
    rec = _recorder(clock)
    rec.on_goto(POSE, 1.0, 1.0)
    clock.t = 1.0 + 9000.0  # two and a half hours later
    rec.on_goto({**POSE, "z": 0.2}, 1.0, 1.0)
    script = parse_maneuver(rec.stop("taught"))  # raised a ManeuverError (wait > 3600 s) before
    waits = [s.seconds for s in script.steps if s.kind == "wait"]
    assert waits == [3600.0, 3600.0, 1800.0]


def test_a_drive_beyond_one_wait_for_distance_step_is_recorded_as_several_and_parses():
    clock, odometer = _Clock(), [0.0]
    rec = _recorder(clock, odometer)
    rec.on_goto(POSE, 1.0, 1.0)
    clock.t, odometer[0] = 2001.0, 25_000.0  # 25 km in 2001 s, 2000 s of them after the 1 s motion
    rec.on_goto({**POSE, "z": 0.2}, 1.0, 1.0)
    script = parse_maneuver(rec.stop("taught"))  # raised a ManeuverError (distance > 10000 m) before
    distances = [s.distance for s in script.steps if s.kind == "wait_for"]
    assert distances[:2] == [10_000.0, 10_000.0] and len(distances) == 3
    assert sum(distances) == pytest.approx(25_000.0 * 2000.0 / 2001.0, abs=0.01)  # the pause's share


def test_the_pause_after_a_jog_counts_the_distance_driven_in_it():
    """A field operator's report: jog, a 3 s pause while the tractor drove 4.6 m, then a preset: recorded as
    `wait: 3.1` (the jog was closed at the preset, and the odometer read then counted the pause as 0 m)."""
    clock, odometer = _Clock(), [0.0]
    rec = _recorder(clock, odometer)
    rec.on_goto(POSE, 1.0, 1.0)
    speed = 1.5  # m/s, all the time
    for k in range(11):  # a jog held 1 s (commands every 0.1 s, 0.2 s each) after the goto
        clock.t = 2.0 + 0.1 * k
        odometer[0] = speed * clock.t
        rec.on_jog(0.2)
    clock.t = 3.2 + 3.0  # the jog's last command lived until 3.2 s; 3 s later a preset
    odometer[0] = speed * clock.t
    rec.on_preset("work", None, 1.0)
    steps = parse_maneuver(rec.stop("taught")).steps
    kinds = [s.kind for s in steps]
    assert kinds == ["goto", "wait_for", "goto", "wait_for", "preset"], kinds
    assert steps[3].distance == pytest.approx(speed * 3.0, abs=0.01)  # the pause after the jog


def test_concurrent_commands_lose_no_step():
    clock = _Clock()
    rec = _recorder(clock)
    n, threads = 200, 4
    start = threading.Barrier(threads)

    def go(k: int) -> None:
        start.wait(timeout=10.0)
        for i in range(n):
            rec.on_preset(f"p{k}-{i}", None, 0.0)

    workers = [threading.Thread(target=go, args=(k,)) for k in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join(timeout=30.0)
    assert len(rec.steps) == min(MAX_STEPS, n * threads) and rec.dropped == max(0, n * threads - MAX_STEPS)


def test_the_time_before_the_first_command_is_not_a_pause():
    """A new user's report: record start, drive 2 m, goto, record stop gave a first step
    ``wait_for: {distance: 1.95}``; a pause is the time between a motion's end and the next command."""
    clock, odometer = _Clock(), [0.0]
    rec = _recorder(clock, odometer)
    clock.t, odometer[0] = 5.0, 2.0  # 5 s and 2 m after record/start
    rec.on_goto(POSE, 1.0, 1.0)
    clock.t = 6.0 + 3.0  # a 3 s pause after the first motion's end: kept
    rec.on_jog(0.5)
    clock.t = 12.0
    rec.on_goto({**POSE, "z": 0.2}, 1.0, 1.0)
    script = parse_maneuver(rec.stop("taught"))
    assert [s.kind for s in script.steps][:2] == ["goto", "wait"], script.steps
