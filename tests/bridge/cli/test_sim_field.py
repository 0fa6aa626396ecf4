"""CLI: ``hitch sim field FIELD`` on the shipped chisel field, as a user runs it (real subprocess)."""

import json
import subprocess
import sys
from pathlib import Path

HITCH = [str(Path(sys.executable).with_name("hitch"))]


def test_sim_field_runs_draft_control_and_writes_a_png_and_json(tmp_path):
    png, js = tmp_path / "field.png", tmp_path / "field.json"
    r = subprocess.run(
        HITCH
        + ["sim", "field", "chisel", "--mode", "draft", "--draft-setpoint", "21000", "--depth-min", "0.1"]
        + ["--depth-max", "0.3", "--slip-limit", "0.2", "--duration", "8", "--plot", str(png), "--json", str(js)],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert r.returncode == 0, r.stderr
    assert "chisel: mode draft" in r.stdout and "draft mean" in r.stdout and "references_outside_strokes 0" in r.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    d = json.loads(js.read_text())
    assert d["field"] == "chisel" and d["mode"] == "draft" and d["settings"]["draft_setpoint_n"] == 21000.0
    assert d["settings"]["slip_limit"] == 0.2 and d["counts"]["fallbacks"] == 0
    assert 5000.0 < d["figures"]["draft_mean_n"] < 40000.0


def test_sim_field_names_a_bad_field_and_a_bad_setting():
    r = subprocess.run(HITCH + ["sim", "field", "moon"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "moon" in r.stderr and "chisel" in r.stderr
    r = subprocess.run(
        HITCH + ["sim", "field", "chisel", "--mode", "mixed", "--blend", "1.5"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "blend" in r.stderr and "[0, 1]" in r.stderr


def test_sim_field_takes_the_draft_setpoint_in_kn_as_work_settings_does(capsys):
    from bridge.cli.main import main

    base = ["sim", "field", "chisel", "--mode", "draft", "--duration", "7", "--json"]
    assert main([*base, "--draft-setpoint-kn", "18.5"]) == 0
    kn = json.loads(capsys.readouterr().out)
    assert main([*base, "--draft-setpoint", "18500"]) == 0
    n = json.loads(capsys.readouterr().out)
    assert kn["settings"]["draft_setpoint_n"] == 18500.0 == n["settings"]["draft_setpoint_n"]
    timing = ("cpu", "cycle")  # wall-clock costs differ between runs; every simulated figure is the same
    assert {k: v for k, v in kn["figures"].items() if not any(t in k for t in timing)} == {
        k: v for k, v in n["figures"].items() if not any(t in k for t in timing)
    }
    assert main([*base, "--draft-setpoint-kn", "18500"]) == 2  # N given as kN: out of (0, 300] kN
    assert "--draft-setpoint-kn must lie in (0, 300] kN, got 18500" in capsys.readouterr().err
