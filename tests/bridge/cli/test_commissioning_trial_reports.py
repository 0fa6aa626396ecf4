"""A new user's commissioning trial following docs/commissioning.md: what the reports said and what they must say.

Truth, independent of the code under test: the twin's instrument (measure-twin's station noise is 1 mm /
1 mrad, so a tape's σ of 5.8 mm / 11.5 mrad overstates it 6–12 times); the shipped thesis profile, whose
``[workspace.restricted.2]`` box is the fitted box of its geometry (its comments name the limits that stopped
each face); the values written in a profile file (the lag of the pin play); the thesis's tables (which give no
count of measured poses); the calendar date of the run.
"""

from __future__ import annotations

import datetime as _dt
import json
import re
import tomllib
from pathlib import Path

import pytest

import planner.profiles
from bridge.cli.main import main
from bridge.sim.truth import PinPlay, perturb_profile, truth_toml
from planner.calibration import read_calibration_provenance
from planner.calibration.measurements import load_plan_targets
from planner.profiles.hitch import load_profile
from tests.helpers import profile_file_with_final_approach

BUILTIN = Path(planner.profiles.__file__).parent / "thesis-t132.toml"
TAPE_SIGMA = ["--sigma-position-mm", "5.8", "--sigma-angle-mrad", "11.5"]
STATION_SIGMA = ["--sigma-position-mm", "1", "--sigma-angle-mrad", "1"]


@pytest.fixture(scope="module")
def station_csv(tmp_path_factory):
    """12 planned poses of a tape-perturbed thesis twin (seed 11, no play) measured with a total station."""
    folder = tmp_path_factory.mktemp("station")
    data, _ = perturb_profile(load_profile("thesis-t132"), 11)
    truth = folder / "truth.toml"
    truth.write_text(truth_toml(data, PinPlay(0.0, 0.0)))
    meas = folder / "m.csv"
    argv = ["calibrate", "measure-twin", "--sim-truth", str(truth), "--out", str(meas), "--noise", "station"]
    assert main([*argv, "--n", "12", "--candidates", "80", "--seed", "2"]) == 0
    return meas


def _geometry(capsys, meas, out, *extra, json_out=True):
    argv = ["calibrate", "geometry", "--measurements", str(meas), "--out", str(out), *extra]
    rc = main([*argv, "--json"] if json_out else argv)
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


# --- 1. a σ far larger than the scatter -------------------------------------------------------------------------


def test_a_tape_sigma_on_total_station_data_is_warned_naming_the_ratio_and_the_options(station_csv, tmp_path, capsys):
    """The trial: the doc's tape σ on total-station data gave sigma-hat 0.14 without a word and identified 12 of
    21 directions where the station's own σ identified 16."""
    capsys.readouterr()
    out = tmp_path / "tape.toml"
    rc, text, err = _geometry(capsys, station_csv, out, *TAPE_SIGMA)
    assert rc == 0 and out.is_file()  # small residuals are not wrong data: written
    tape = json.loads(text)
    warning = next((ln for ln in err.splitlines() if "scatter" in ln), None)
    assert warning is not None and warning.startswith("hitch: warning: sigma-hat"), err
    times = float(re.search(r"scatter ([0-9.]+)× less than the σ given", warning).group(1))  # type: ignore[union-attr]
    # the station's σ is 1 mm / 1 mrad, the σ given 5.8 mm / 11.5 mrad: the data scatter 6 to 12 times less
    assert 4.0 < times < 15.0, warning
    assert "--sigma-position-mm" in warning and "--sigma-angle-mrad" in warning
    assert "identified" in warning and "standard deviations" in warning
    # what the warning claims: with the station's own σ the fit identifies more, and says nothing of scatter
    rc, text, err = _geometry(capsys, station_csv, tmp_path / "station.toml", *STATION_SIGMA)
    station = json.loads(text)
    assert rc == 0 and "scatter" not in err, err
    assert 0.5 < station["residual_sigma"] < 2.0
    assert station["identified"] > tape["identified"]


# --- 2. the text and the profile's record say the same --------------------------------------------------------


def test_the_text_report_and_the_profile_record_use_the_same_words_for_every_parameter(station_csv, tmp_path, capsys):
    """The trial: the text marked lower_link_pivot_span, lower_link_length … "not identified", the record listed
    only pivot_height under not_identified and gave the others a std."""
    capsys.readouterr()
    out = tmp_path / "cal.toml"
    rc, text, err = _geometry(capsys, station_csv, out, *STATION_SIGMA, json_out=False)
    assert rc == 0, err
    prov = read_calibration_provenance(out)
    assert prov is not None
    lines = {n: ln for ln in text.splitlines() for n in prov["identified_share"] if ln.strip().startswith(n + " ")}
    assert set(lines) == set(prov["identified_share"])  # a line for every parameter
    weakly = set(prov["weakly_identified"])
    assert weakly, "the trial's data leave parameters weakly identified"
    for name, line in lines.items():
        says_not = "not identified" in line
        assert says_not == (name in prov["not_identified"]), (name, line)
        # no std in the record <=> none in the text; a std in the record is printed as ± or σ
        assert (name in prov["std"]) == ("±" in line or "σ " in line), (name, line)
        assert ("weakly identified" in line) == (name in weakly), (name, line)
        assert ("% identified*" in line) == (name in prov["partly_identified"]), (name, line)
    # the legend names the record's keys
    assert "not_identified" in text and "weakly_identified" in text


def test_a_calibrated_profile_says_it_is_calibrated_not_tape_measured(station_csv, tmp_path, capsys):
    capsys.readouterr()
    out = tmp_path / "cal.toml"
    rc, _, err = _geometry(capsys, station_csv, out, *STATION_SIGMA)
    assert rc == 0, err
    day = _dt.datetime.now(_dt.UTC).date().isoformat()
    desc = load_profile(out).description
    nominal = load_profile("thesis-t132").description
    assert "(tape-measured)" in nominal and "tape-measured" not in desc, desc
    assert desc.startswith("Valtra T132 advanced rear hitch, geometry of thesis table 3-5"), desc
    assert desc.endswith(f"calibrated {day} from 12 poses (hitch calibrate geometry)"), desc
    # calibrated again from it: one note, the latest
    again = tmp_path / "again.toml"
    rc, _, err = _geometry(capsys, station_csv, again, *STATION_SIGMA, "--profile", str(out))
    assert rc == 0, err
    assert load_profile(again).description.count("calibrated") == 1


# --- 3. fit-workspace writes the box ---------------------------------------------------------------------------


def _shipped_box(category: str) -> dict:
    return tomllib.loads(BUILTIN.read_text())["workspace"]["restricted"][category]


def test_fit_workspace_write_replaces_the_box_and_keeps_every_other_line(tmp_path, capsys):
    """The trial: fit-workspace printed a box, and the user edited [workspace.restricted.2] by hand."""
    rows = BUILTIN.read_text().splitlines()
    at = rows.index("[workspace.restricted.2]")
    edited = [*rows[: at + 1], "# my own note", "x = [-0.030000, 0.030000]", *rows[at + 2 :]]
    mine = tmp_path / "tractor.toml"
    mine.write_text("\n".join(edited) + "\n")
    assert load_profile(mine).workspace.restricted["2"].x == (-0.03, 0.03)
    capsys.readouterr()
    assert main(["profile", "fit-workspace", "--profile", str(mine), "--write"]) == 0
    assert f"into {mine}" in capsys.readouterr().out
    written = mine.read_text().splitlines()
    # the shipped box is the fitted one of this geometry
    assert tomllib.loads(mine.read_text())["workspace"]["restricted"]["2"] == _shipped_box("2")
    assert load_profile(mine).workspace.restricted["2"].x == (-0.06, 0.06)
    # every other line as it was, the user's comment too
    box = re.compile(r"^(x|z|roll|pitch) = ")
    i = written.index("[workspace.restricted.2]")
    assert written[:i] == edited[:i] and "# my own note" in written[i : i + 6]
    assert [ln for ln in written[i:] if not box.match(ln)][:2] == ["[workspace.restricted.2]", "# my own note"]
    end = written.index("[workspace.restricted.3N]")
    assert written[end:] == edited[edited.index("[workspace.restricted.3N]") :]


def test_fit_workspace_out_writes_a_copy_and_never_a_builtin_profile(tmp_path, capsys):
    before = BUILTIN.read_bytes()
    copy = tmp_path / "copy.toml"
    assert main(["profile", "fit-workspace", "--category", "3", "--out", str(copy), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["written"] == str(copy)
    assert tomllib.loads(copy.read_text())["workspace"]["restricted"]["3"] == _shipped_box("3")
    assert main(["profile", "fit-workspace", "--write"]) == 2  # the built-in thesis-t132
    assert "built-in profile" in capsys.readouterr().err
    assert main(["profile", "fit-workspace", "--profile", str(BUILTIN), "--write"]) == 2
    assert "built-in profiles" in capsys.readouterr().err
    assert BUILTIN.read_bytes() == before


# --- 4. units and names ----------------------------------------------------------------------------------------


def test_profile_show_prints_the_neutral_pose_workspace_and_lag_with_units(tmp_path, capsys):
    path = profile_file_with_final_approach(tmp_path)
    lag = {"x": 0.000556913, "z": 0.0012, "roll": 0.0004, "pitch": -0.0011}
    path.write_text(
        path.read_text() + "\n[motion.final_approach.lag]\n" + "".join(f"{k} = {v}\n" for k, v in lag.items())
    )
    capsys.readouterr()
    assert main(["profile", "show", "--profile", str(path)]) == 0
    out = capsys.readouterr().out
    neutral = next(ln for ln in out.splitlines() if ln.startswith("neutral pose:"))
    for k, unit in (("x", "m"), ("y", "m"), ("z", "m"), ("roll", "rad"), ("pitch", "rad"), ("yaw", "rad")):
        assert re.search(rf"\b{k}=[+-]\d+\.\d+ {unit}\b", neutral), neutral
    box = next(ln for ln in out.splitlines() if ln.startswith("restricted workspace:"))
    for k, unit in (("x", "m"), ("z", "m"), ("roll", "rad"), ("pitch", "rad")):
        assert re.search(rf"\b{k} \[[^]]+\] {unit}\b", box), box
    approach = next(ln for ln in out.splitlines() if ln.startswith("final approach:"))
    shown = approach.split("lag of the pin play:")[1]
    assert "0.000556913" not in approach
    for k, v in lag.items():  # the profile's values (m, rad) in mm / mrad, named
        unit = "mm" if k in ("x", "z") else "mrad"
        assert f"{k}={1e3 * v:+.3f} {unit}" in shown, shown
    assert "x=+2.500 mm" in approach.split(";")[0]  # the offsets (2.5 mm) too


def test_plan_poses_names_the_actuators_of_its_counts_and_rounds_its_template(tmp_path, capsys):
    plan = tmp_path / "plan.csv"
    argv = ["calibrate", "plan-poses", "--n", "4", "--candidates", "40", "--out", str(plan)]
    assert main(argv) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if re.match(r"\s*p\d+:", ln)]
    assert len(lines) == 4
    for ln in lines:
        assert re.search(r"counts lift \d+ tilt \d+ top \d+ left \d+ right \d+$", ln), ln
    assert main([*argv[:-2], "--json"]) == 0
    poses = json.loads(capsys.readouterr().out)["poses"]
    header, *rows = plan.read_text().splitlines()
    cols = header.split(",")
    for row in rows:
        for name, cell in zip(cols, row.split(","), strict=True):
            if name.startswith("target_"):  # 1 µm / 1 µrad: at most 6 decimals
                assert re.fullmatch(r"-?\d+\.\d{6}", cell), (name, cell)
    labels, targets = load_plan_targets(plan)  # read back
    assert labels == tuple(p["pose"] for p in poses)
    for p, t in zip(poses, targets, strict=True):
        assert [p[k] for k in ("x", "z", "roll", "pitch")] == pytest.approx(list(t), abs=5.1e-7)


# --- 5. accuracy-test reports the deflected DOF --------------------------------------------------------------


def test_accuracy_test_of_one_dof_compares_only_it_with_the_thesis_and_explains_its_columns(capsys):
    assert main(["accuracy-test", "--dofs", "z", "--instrument", "station"]) == 0
    out = capsys.readouterr().out.splitlines()
    head = next(i for i, ln in enumerate(out) if ln.startswith("DOF"))
    table = out[head : out.index("", head)]
    assert max(map(len, table)) <= 100, max(map(len, table))
    thesis = [ln for ln in table if " thesis " in ln]
    assert len(thesis) == 3 and all(ln.split()[0] == "z" for ln in thesis)  # the thesis's z rows only
    assert "40.0" in thesis[0]  # the hybrid |E|max of z, 40 mm
    legend = next(ln for ln in table if ln.startswith("E:"))
    assert "mean error" in legend and "|E|:" in legend and "|E|max" in legend and "TT: repeatability" in legend
    # x, roll, pitch were not deflected: marked so, below the comparison
    held = table.index(next(ln for ln in table if ln.startswith("not deflected")))
    for d in ("x", "roll", "pitch"):
        rows = [i for i, ln in enumerate(table) if ln.split()[0] == d]
        assert rows and all(i > held and "held" in table[i] for i in rows), (d, table)


def test_accuracy_test_json_of_one_dof_separates_the_held_dofs_and_the_thesis_count_is_unknown(capsys):
    assert main(["accuracy-test", "--dofs", "z", "--instrument", "station", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["deflected"] == ["z"] and set(out["statistics"]) == {"z"}
    assert out["not_deflected"]["dofs"] == ["x", "roll", "pitch"]
    assert set(out["not_deflected"]["statistics"]) == {"x", "roll", "pitch"}
    # the thesis gives no count of measured poses: null, not 0
    for rows in out["thesis"].values():
        assert all(st["n"] is None for st in rows.values())
    assert out["statistics"]["z"]["n"] == 4  # the twin's: z+ twice, z- twice


def test_fit_workspace_out_in_another_folder_keeps_a_relative_tractor_profile_reachable(tmp_path, monkeypatch, capsys):
    """A profile naming its tractor "my-tractor.toml" (taken from the profile's folder, docs/profiles.md)
    copied to out/: the copy must name it from there."""
    from tests.helpers import profiles_with_own_tractor

    profiles_with_own_tractor(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert main(["profile", "fit-workspace", "--profile", "prof/mine.toml", "--out", "out/fitted.toml"]) == 0
    capsys.readouterr()
    tractor = Path(load_profile("out/fitted.toml").stability.tractor_profile).resolve()
    assert tractor == (tmp_path / "prof" / "my-tractor.toml").resolve()
