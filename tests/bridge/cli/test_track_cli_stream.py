"""``hitch track`` streaming against a stand-in service (:class:`FakeService`, no network): the last setpoint of a
signal is sent even when the stream runs late, SIGHUP (the terminal closed) sends ``track/stop`` with the last
``seq`` as SIGTERM and Ctrl-C do, and the end note tells the stop's braking distance from a signal the hitch
could not follow."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from bridge.cli import track as cli_track
from bridge.cli.main import main
from tests.integration.service_process import ROOT

DOFS = ("x", "z", "roll", "pitch")


class FakeService:
    """Stands in for a :class:`~bridge.service.client.HitchClient` and the service behind it: every setpoint
    taken is answered by a state whose measured pose is the setpoint ``lag`` [m] behind in z (commanded z
    velocity ``v_stop`` [m/s], ``limited`` what limited the control); ``track/stop`` brakes, the hitch
    coming to rest ``braking`` [m] beyond where it was, and the session finishes (``track/stop``)."""

    SESSION, MOTION = 7, 70

    def __init__(
        self,
        *,
        lag: float = 0.0,
        braking: float = 0.0,
        v_stop: float = 0.0,
        limited: dict | None = None,
        slow_put_s: float = 0.0,
        hup_at: int | None = None,
        lose_events: bool = False,
        end: tuple[str, str] = ("motion_finished", "track/stop"),
        intruder_seq: int | None = None,
        keeps_events: bool = False,
        instance: str = "run-1",
        events_instance: str = "run-1",
    ) -> None:
        self.instance, self.events_instance = instance, events_instance  # config's run; the run events/recent is of
        self.keeps_events = keeps_events  # events/recent answers the end event its subscription missed
        self.intruder_seq = intruder_seq  # another client's seq taken into the session: ours ignored from then
        self.lag, self.braking, self.v_stop, self.limited = lag, braking, v_stop, dict(limited or {})
        self.end = end  # the session's end event and reason (another than track/stop: it ended before the stop)
        self.slow_put_s, self.hup_at = slow_put_s, hup_at
        self.lose_events = lose_events  # the events key cut (a router restart): the end is seen in the state only
        self.callbacks: dict = {}
        self.sent: list[tuple[int, dict]] = []
        self.stops: list[tuple[int | None, int | None]] = []
        self.z = 0.1

    def subscribe(self, what, callback):
        self.callbacks[what] = callback

    def _pose(self) -> dict:
        return {"x": 0.0, "z": self.z, "roll": 0.0, "pitch": 0.0}

    def state(self) -> dict:
        return {"pose": self._pose(), "track": None, "limited": {}}

    def track_start(self, frame, dofs, ttl_ms, *, replace=False):
        self.replace = replace
        return {"session": self.SESSION, "motion_id": self.MOTION, "frame": frame, "dof": list(dofs), "ttl_ms": ttl_ms}

    def _publish(self, *, ending: bool, velocity: float) -> None:
        tr = {
            "session": self.SESSION,
            "setpoints": len(self.sent),
            "rejected": 0,
            "ignored_seq": 0 if self.intruder_seq is None else len(self.sent),
            "last_seq": self.intruder_seq
            if self.intruder_seq is not None
            else (self.sent[-1][0] if self.sent else None),
            "ending": ending,
            "control_limited": {} if ending else dict(self.limited),
        }
        vel = dict.fromkeys(DOFS, 0.0) | {"z": velocity}
        self.callbacks["state"]({"pose": self._pose(), "velocity": vel, "limited": {}, "track": tr})

    def _take(self, seq: int, pose: dict) -> None:
        self.sent.append((seq, dict(pose)))
        self.z = pose["z"] - self.lag
        self._publish(ending=False, velocity=self.v_stop)
        if seq == self.hup_at:
            os.kill(os.getpid(), signal.SIGHUP)
        if self.slow_put_s and seq > 0:
            time.sleep(self.slow_put_s)

    def track_setpoint_request(self, session, seq, pose, velocity=None, *, timeout_s=None):
        self._take(seq, pose)
        return {"accepted": True, "limited": {}, "session": session, "seq": seq}

    def track_setpoint(self, session, seq, pose, velocity=None):
        self._take(seq, pose)

    def recent_events(self, after=0):
        if not self.keeps_events:
            raise AttributeError("recent_events")  # as an older service's client: no such key
        end = {"seq": 41, "event": self.end[0], "motion_id": self.MOTION, "kind": "track", "reason": self.end[1]}
        return {
            "events": [end] if after < 41 else [],
            "latest": 41,
            "oldest": 1,
            "missed": False,
            "more": False,
            "instance": self.events_instance,
        }

    def config(self):
        return {"instance": self.instance}

    def track_stop(self, session=None, *, last_seq=None, timeout_s=None):
        self.stops.append((session, last_seq))
        self.z += self.braking
        self._publish(ending=True, velocity=0.0)
        self.callbacks["state"]({"pose": self._pose(), "velocity": dict.fromkeys(DOFS, 0.0), "track": None})
        if not self.lose_events:
            self.callbacks["events"](
                {"event": self.end[0], "motion_id": self.MOTION, "kind": "track", "reason": self.end[1]}
            )
        return {"stopping": True, "session": session, "motion_id": self.MOTION}


def _run_with(monkeypatch, fake: FakeService, *argv: str) -> int:
    monkeypatch.setattr(cli_track, "_run", lambda args, fn: fn(fake))
    return main(["track", *argv])


def test_the_last_row_of_a_file_is_sent_even_when_the_stream_runs_late(monkeypatch, capsys, tmp_path):
    """A late stream skips to the setpoint of now; it skipped the last one too, and the hitch did not end where
    the recording ends."""
    f = tmp_path / "s.csv"
    f.write_text("t,z\n0,0.10\n0.1,0.11\n0.21,0.13\n")
    fake = FakeService(slow_put_s=0.08)  # every put takes 80 ms: a loaded machine
    assert _run_with(monkeypatch, fake, "--from-file", str(f)) == 0
    capsys.readouterr()
    seq, pose = fake.sent[-1]
    assert pose["z"] == pytest.approx(0.13) and fake.stops == [(7, seq)], fake.sent


def test_the_end_note_names_the_stop_s_braking_distance_when_the_hitch_followed(monkeypatch, capsys):
    """The README's quick-start sine (63 mm/s, unclipped) ended with "the signal ran faster than the hitch may
    follow": its +7.4 mm are the braking distance of track/stop from the velocity the hitch had (as measured on a
    real service: 7.4 mm behind the last setpoint as the stop began, 14.8 mm travelled after it)."""
    fake = FakeService(lag=0.0074, braking=0.0148, v_stop=0.0623)
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.2") == 0
    err = capsys.readouterr().err
    assert "ran faster than the hitch may follow" not in err, err
    assert err.startswith(
        "hitch: note: the hitch came to rest z +7.4 mm beyond the last setpoint sent (end pose minus setpoint): the "
        "braking distance of track/stop, which brakes from the velocity the hitch had (z +62.3 mm/s); it travelled "
        "z +14.8 mm after the stop began"
    ), err


@pytest.mark.parametrize(
    ("lag", "braking", "limited", "words"),
    [
        # far behind (a file far from where the hitch stood): it ends short of the last setpoint
        (0.03, 0.003, None, "(z -27.0 mm: end pose minus setpoint; it travelled z +3.0 mm after the stop began)"),
        # beyond the last setpoint by more than it braked
        (-0.004, 0.005, None, "(z +9.0 mm: end pose minus setpoint; it travelled z +5.0 mm after the stop began)"),
        # within its braking distance, but the control was limited as the stop began: the signal asked too much
        (0.0005, 0.009, {"vz": "velocity:z"}, "(z +8.5 mm: end pose minus setpoint; it travelled z +9.0 mm after the "),
    ],
)
def test_the_end_note_blames_the_signal_beyond_the_braking_distance_or_when_limited(
    monkeypatch, capsys, lag, braking, limited, words
):
    fake = FakeService(lag=lag, braking=braking, v_stop=0.05, limited=limited)
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.2", "--json") == 0
    out = capsys.readouterr()
    assert out.err.startswith("hitch: note: the hitch ended away from the last setpoint sent " + words), out.err
    assert "the signal ran faster than the hitch may follow" in out.err
    assert ("control limited as the stop began: " in out.err) == bool(limited)
    assert json.loads(out.out)["end_braking"] == {"z": pytest.approx(braking)}


@pytest.mark.parametrize(
    "end",
    [("motion_finished", "stale: no setpoint within 200 ms"), ("motion_aborted", "fault: ecu_heartbeat")],
)
def test_a_session_that_ended_before_track_stop_names_its_end_not_the_signal(monkeypatch, capsys, end):
    """A field trial: after a stale stream and after a killed ECU the note said "the signal ran faster than the
    hitch may follow, or it began far from where the hitch stood"."""
    fake = FakeService(lag=0.03, braking=0.003, v_stop=0.05, end=end)
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.2") == 1
    err = capsys.readouterr().err
    assert "ran faster than the hitch may follow" not in err, err
    assert (
        f"hitch: note: the hitch ended away from the last setpoint sent (z -27.0 mm: end pose minus setpoint): the "
        f"session ended before track/stop — {end[1]}" in err
    ), err


def test_a_stream_another_client_took_over_by_seq_is_told_so(monkeypatch, capsys):
    """A fleet re-run: another client's put with seq 1e9 had this stream ignored until the session went stale;
    the CLI blamed the signal."""
    fake = FakeService(end=("motion_finished", "stale: no setpoint within 200 ms"), intruder_seq=10**9)
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.2") == 1
    err = capsys.readouterr().err
    assert "session 7 took seq 1000000000, above the last this stream sent (" in err, err
    assert "another client sent into this session" in err and "ran faster than the hitch may follow" not in err


@pytest.mark.parametrize("flag", [[], ["--replace"]])
def test_replace_takes_over_another_clients_session_only_when_asked(monkeypatch, capsys, flag):
    fake = FakeService()
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.1", "--json", *flag) == 0
    assert fake.replace is bool(flag)


def test_a_session_whose_end_event_was_not_heard_is_outcome_unknown_not_success(monkeypatch, capsys):
    """A fleet trial: `hitch track` through a router restart printed "ended: -" and exited 0, though the
    service had aborted the session (link lost). Without the motion's own end event the outcome is unknown."""
    fake = FakeService(lose_events=True)
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.1") == 1
    err = capsys.readouterr().err
    assert "hitch: outcome UNKNOWN: session 7 (motion 70) ended, but its end event was not heard" in err, err
    assert "stop the hitch another way" not in err
    # the summary says so, and no end note blames the signal (a new user's trial: "ended: -", then "the signal ran
    # faster than the hitch may follow" after a router restart)
    fake = FakeService(lose_events=True, braking=0.02, v_stop=0.05)
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.1") == 1
    out = capsys.readouterr()
    assert "ended: outcome unknown (its end event was not heard)" in out.out and "ended: -" not in out.out, out.out
    assert "the signal ran faster" not in out.err, out.err
    # --json keeps reason the service's own (none heard) and says outcome_unknown (a review: made-up text in reason)
    fake = FakeService(lose_events=True)
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.1", "--json") == 1
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["reason"] is None and summary["outcome_unknown"] is True, summary


def test_a_missed_end_event_is_asked_for_afterwards_and_the_outcome_is_known(monkeypatch, capsys):
    """A field trial: after a frozen service `hitch track` said "outcome UNKNOWN" though the black box had the
    end; the service keeps its recent events (events/recent) and the CLI asks for the one it missed."""
    fake = FakeService(lose_events=True, keeps_events=True)
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.1", "--json") == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["reason"] == "track/stop" and summary["outcome_unknown"] is False, summary
    fake = FakeService(lose_events=True, keeps_events=True, end=("motion_aborted", "link lost"))
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.1") == 1
    err = capsys.readouterr().err
    assert "outcome UNKNOWN" not in err, err
    # the service restarted meanwhile: its events are another run's, its motion 70 another motion (a review)
    fake = FakeService(lose_events=True, keeps_events=True, events_instance="run-2")
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.1") == 1
    assert "outcome UNKNOWN" in capsys.readouterr().err


SIGHUP_SCRIPT = """
import json
from bridge.cli import track
from bridge.cli.main import main
from tests.bridge.cli.test_track_cli_stream import FakeService
fake = FakeService(hup_at=5)
track._run = lambda args, fn: fn(fake)
code = main(["track", "--sine", "z=0.02@0.5Hz", "--duration", "2"])
print(json.dumps({"code": code, "stops": fake.stops, "sent": [s for s, _ in fake.sent]}))
"""


@pytest.mark.skipif(not hasattr(signal, "SIGHUP"), reason="POSIX only")
def test_sighup_sends_track_stop_with_the_last_seq_as_sigterm_does():
    """A new user's report: closing the terminal (SIGHUP) ended `hitch track` without track/stop; the service
    braked only at the ttl."""
    r = subprocess.run([sys.executable, "-c", SIGHUP_SCRIPT], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, (r.returncode, r.stderr)
    out = json.loads(r.stdout.splitlines()[-1])
    assert out["code"] == 130 and out["sent"] == [0, 1, 2, 3, 4, 5], out
    assert out["stops"] == [[7, 5]], out
    assert "hitch: hung up (SIGHUP: the terminal closed): sending track/stop (session 7)" in r.stderr, r.stderr


def test_without_a_state_before_the_stop_the_note_names_both_causes():
    note, braking = cli_track._end_note({"z": 0.0074}, None, {"x": 0.0, "z": 0.1074, "roll": 0.0, "pitch": 0.0})
    assert braking is None and note is not None
    assert "(z +7.4 mm: end pose minus setpoint)" in note and "or it braked that far after track/stop" in note
    assert cli_track._end_note({"z": 0.004}, None, {"z": 0.1}) == (None, None)  # within 5 mm: nothing to say


class _LosesAPut(FakeService):
    """A put lost on the way (dropped under congestion): the service never takes that seq."""

    def track_setpoint(self, session, seq, pose, velocity=None):
        if seq != 2:
            self._take(seq, pose)


def test_a_put_lost_in_the_middle_is_not_called_sent_after_the_session_ended(monkeypatch, capsys):
    """A field trial: 151 setpoints sent, 150 taken, the last one among them and the session ended by its own
    track/stop; the summary said "setpoints sent after the session ended were not taken"."""
    fake = _LosesAPut()
    assert _run_with(monkeypatch, fake, "--sine", "z=0.02@0.5Hz", "--duration", "0.2") == 0
    out = capsys.readouterr().out
    assert "after the session ended" not in out, out
    assert "1 setpoint put(s) did not reach the service (a put is dropped, never queued)" in out, out
