"""Every command that writes a profile (``sim perturb``, ``calibrate sensors``, ``calibrate geometry``) from a
profile that names its own tractor profile by a relative path: the written file loads from its folder.

A commissioning engineer's report (truth: the loader takes a relative ``tractor_profile`` from the profile
file's folder, docs/profiles.md): ``calibrate geometry --out prof/cal2.toml`` wrote the path relative to the
working folder ("prof/my-tractor.toml": unloadable, and left on disk), ``calibrate sensors`` and ``sim
perturb`` copied it unchanged into files in another folder.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge.cli.main import main
from bridge.sim.truth import load_machine_truth
from planner.profiles.hitch import load_profile
from tests.helpers import profiles_with_own_tractor


@pytest.fixture
def own_tractor(tmp_path, monkeypatch):
    """prof/mine.toml naming prof/my-tractor.toml as "my-tractor.toml" (profiles_with_own_tractor); cwd = tmp."""
    profiles_with_own_tractor(tmp_path)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _tractor_of(path: str) -> Path:
    return Path(load_profile(path).stability.tractor_profile).resolve()


def test_every_profile_writer_keeps_the_tractor_profile_reachable(own_tractor, capsys):
    mine = own_tractor / "prof" / "my-tractor.toml"
    argv = ["sim", "perturb", "--seed", "3", "--tape", "--profile", "prof/mine.toml"]
    assert main([*argv, "--out", "out/truth.toml"]) == 0
    assert _tractor_of("out/truth.toml") == mine
    assert load_machine_truth("out/truth.toml").profile.stability.tractor_profile.endswith("my-tractor.toml")
    argv = ["calibrate", "sensors", "--profile", "prof/mine.toml", "--sim-truth", "out/truth.toml"]
    assert main([*argv, "--actuators", "top", "--out", "out/sensors.toml"]) == 0
    assert _tractor_of("out/sensors.toml") == mine
    argv = ["calibrate", "measure-twin", "--profile", "prof/mine.toml", "--sim-truth", "out/truth.toml"]
    assert main([*argv, "--n", "12", "--candidates", "60", "--out", "out/m.csv"]) == 0
    for out in ("prof/cal.toml", "out/cal.toml"):
        argv = ["calibrate", "geometry", "--profile", "prof/mine.toml", "--measurements", "out/m.csv"]
        assert main([*argv, "--out", out]) == 0, capsys.readouterr().err
        assert _tractor_of(out) == mine
    capsys.readouterr()


def test_profile_show_names_the_sensor_calibration_a_profile_records(tmp_path, capsys):
    """A commissioning trial: ``profile show`` did not show the calibration record a profile carries (only its
    comment line did). Truth: the record written by the sensor calibration's own writer."""
    from bridge.link.sensor_calibration import sensor_profile_toml

    out = tmp_path / "sensors.toml"
    when = "2026-12-07T17:30:16+00:00"
    out.write_text(sensor_profile_toml("thesis-t132", {"lift": (40, 990)}, provenance={"date": when, "machine": "t01"}))
    assert main(["profile", "show", "--profile", str(out)]) == 0
    assert f"sensor calibration: {when} (its AD maps measured at the end stops)" in capsys.readouterr().out
    assert main(["profile", "show", "--profile", "thesis-t132"]) == 0  # a built-in profile: no record
    assert "calibration:" not in capsys.readouterr().out
