"""``hitch maneuver save --replace``, ``record stop --save NAME --replace`` and a skip that finished the
maneuver, against a stand-in client (what the CLI sends and prints)."""

from __future__ import annotations

import pytest

from bridge.cli import service as cli_service
from bridge.cli.main import main


class _Client:
    def __init__(self, reply):
        self.calls: list = []
        self.reply = reply

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def request(self, key, payload=None, **kw):
        self.calls.append((key, payload))
        return self.reply


@pytest.fixture
def client(monkeypatch):
    holder = {}

    def make(reply):
        c = _Client(reply)
        holder["c"] = c
        monkeypatch.setattr(cli_service, "_client", lambda args: c)
        return c

    return make


def test_save_sends_replace_only_when_asked_and_says_replaced(client, capsys, tmp_path):
    f = tmp_path / "m.yaml"
    f.write_text("steps:\n  - wait: 1\n")
    c = client({"saved": "lift", "steps": 1})
    assert main(["maneuver", "save", "lift", str(f)]) == 0
    assert c.calls == [("maneuvers/save", {"name": "lift", "script": "steps:\n  - wait: 1\n"})]
    assert "saved lift (1 step;" in capsys.readouterr().out
    c = client({"saved": "lift", "steps": 1, "replaced": True})
    assert main(["maneuver", "save", "lift", str(f), "--replace"]) == 0
    assert c.calls == [("maneuvers/save", {"name": "lift", "script": "steps:\n  - wait: 1\n", "replace": True})]
    assert "replaced lift (1 step;" in capsys.readouterr().out


def test_record_stop_replace_needs_save_and_is_sent(client, capsys):
    c = client({"script": "steps:\n- wait: 1\n", "steps": 1, "saved": "lift", "replaced": True})
    assert main(["maneuver", "record", "stop", "--save", "lift", "--replace"]) == 0
    assert c.calls == [("maneuvers/record/stop", {"name": "lift", "replace": True})]
    assert "replaced lift (1 steps)" in capsys.readouterr().out
    c = client({"script": "steps:\n- wait: 1\n", "steps": 1})
    assert main(["maneuver", "record", "stop", "--replace"]) != 0
    assert c.calls == [] and "--replace needs" in capsys.readouterr().err


def test_a_skip_of_the_last_step_prints_finished(client, capsys):
    """It printed ``skip: maneuver 10 paused, step None`` (the maneuver then sat paused)."""
    client({"action": "skip", "maneuver_id": 10, "maneuver": None})
    assert main(["maneuver", "skip"]) == 0
    assert capsys.readouterr().out.strip() == "skip: maneuver 10 finished (no step left)"


def test_serve_notes_an_unsaved_recording_in_the_black_box_when_it_stops(monkeypatch, tmp_path, capsys):
    """An unsaved teach-in recording was discarded without trace when the service stopped."""
    from types import SimpleNamespace

    from bridge.service.blackbox import event_log_path, read_events
    from bridge.service.maneuvers.recorder import ManeuverRecorder

    rec = ManeuverRecorder(lambda: 0.0, lambda: {"x": 0.0, "z": 0.0, "roll": 0.0, "pitch": 0.0}, lambda: None)
    rec.on_goto({"z": 0.1}, 1.0, 1.0)
    rec.on_goto({"z": 0.2}, 1.0, 1.0)
    service = SimpleNamespace(
        warnings=[], http=None, add_listener=lambda *a: None, api=SimpleNamespace(recorder=rec, on_request=None)
    )

    _serve_once(monkeypatch, tmp_path, service)
    records = [r for r in read_events(event_log_path(tmp_path)) if r.get("kind") == "service"]
    assert [r["what"] for r in records] == ["started", "recording_discarded", "stopped"], records
    assert records[1]["steps"] == 2 and "2 step(s) was discarded" in records[1]["message"]


def test_serve_names_the_selected_implement_in_its_started_record(monkeypatch, tmp_path):
    """After a restart the log did not say which implement the guard plans with: its implement_selected event
    is published before the black box is attached."""
    from types import SimpleNamespace

    from bridge.service.blackbox import event_log_path, read_events

    service = SimpleNamespace(
        warnings=[],
        http=None,
        add_listener=lambda *a: None,
        api=SimpleNamespace(recorder=None, on_request=None, implement="cat2-power-harrow-1500"),
    )

    _serve_once(monkeypatch, tmp_path, service)
    started = [r for r in read_events(event_log_path(tmp_path)) if r.get("what") == "started"]
    assert started and started[0]["implement"] == "cat2-power-harrow-1500", started


def _serve_once(monkeypatch, tmp_path, service) -> None:
    """``hitch serve`` around ``service`` (a stand-in): it is ready, then stops at once."""
    import bridge.service.server as server

    def fake_serve(cfg, ready, data_lock=None):
        ready(service)
        return 0.01

    monkeypatch.setattr(server, "serve", fake_serve)
    assert main(["serve", "--data-dir", str(tmp_path)]) == 0
