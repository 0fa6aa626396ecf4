"""CLI: ``hitch sim track SCENARIO`` on the shipped flat scenario, as a user runs it (real subprocess)."""

import json
import subprocess
import sys
from pathlib import Path

HITCH = [str(Path(sys.executable).with_name("hitch"))]


def test_sim_track_runs_the_flat_scenario_and_writes_a_png_and_json(tmp_path):
    png, js = tmp_path / "track.png", tmp_path / "track.json"
    r = subprocess.run(
        HITCH + ["sim", "track", "flat", "--duration", "7", "--plot", str(png), "--json", str(js)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert "error RMS" in r.stdout and "references_outside_strokes 0" in r.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    d = json.loads(js.read_text())
    assert d["scenario"] == "flat" and d["strategy"] == "track" and d["job"] == "levelling"
    assert d["error"]["max"] < 1e-3  # flat ground: the implement stays level
    assert d["counts"]["refused"] == 0 and d["counts"]["outside_workspace"] == 0


def test_sim_track_names_a_bad_scenario():
    r = subprocess.run(HITCH + ["sim", "track", "moon"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "moon" in r.stderr and "flat" in r.stderr
