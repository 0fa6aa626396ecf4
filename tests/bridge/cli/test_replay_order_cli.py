"""``hitch replay`` of a CAN log stamped a little out of time order (the product's own log through the CAN hub):
replayed in file order, the count in the closing line (``--json``: a last record); a large step back refused."""

from __future__ import annotations

import json

import pytest

from bridge.cli.main import main
from tests.bridge.service.test_replay_order import JITTER_S, JITTERED_TICKS, T0, _ecu_frames, _in_time_order, _write


def test_hitch_replay_says_how_many_frames_were_out_of_time_order_and_by_how_much(tmp_path, capsys):
    """Was: exit 2, "frame 27 … goes back in time from …" on the product's own log."""
    frames = _ecu_frames()
    path = tmp_path / "bus.asc"
    _write(path, frames)
    assert main(["replay", str(path)]) == 0
    last = capsys.readouterr().out.splitlines()[-1]
    assert last.startswith(f"{len(frames)} frames: "), last
    assert last.endswith(
        "; 0 faults raised, 0 cleared; 6 frames out of time order by up to 15.0 ms, taken in file order"
    )
    assert main(["replay", str(path), "--json", "--only", "Heartbeat"]) == 0
    recs = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    assert {r["message"] for r in recs[:-1]} == {"Heartbeat"}
    end = recs[-1]
    assert end["message"] == "out_of_order" and end["source"] is None, end
    assert end["fields"]["frames"] == len(JITTERED_TICKS)
    assert end["fields"]["max_back_s"] == pytest.approx(JITTER_S, abs=2e-6)
    assert end["faults"] == ["6 frames out of time order by up to 15.0 ms, taken in file order"]
    assert end["timestamp"] == pytest.approx(T0 + 1.99, abs=2e-6)


def test_hitch_replay_of_a_log_in_time_order_says_nothing_of_order(tmp_path, capsys):
    path = tmp_path / "bus.asc"
    _write(path, _in_time_order(_ecu_frames()))
    assert main(["replay", str(path)]) == 0
    assert capsys.readouterr().out.splitlines()[-1].endswith("; 0 faults raised, 0 cleared")
    assert main(["replay", str(path), "--json", "--only", "Heartbeat"]) == 0
    assert {json.loads(ln)["message"] for ln in capsys.readouterr().out.splitlines()} == {"Heartbeat"}


def test_hitch_replay_refuses_two_logs_put_together_naming_the_frame_and_both_times(tmp_path, capsys):
    first = _in_time_order(_ecu_frames())
    second = _in_time_order(_ecu_frames())  # the same 2 s again: back by 1.99 s after the first's last frame
    path = tmp_path / "joined.log"
    _write(path, first + second)
    assert main(["replay", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"frame {len(first) + 1} at {T0:.6f} s goes back in time from {T0 + 1.99:.6f} s" in err, err
