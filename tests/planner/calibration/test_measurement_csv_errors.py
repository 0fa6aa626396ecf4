"""A measurement or plan CSV the CSV reader cannot read (a stray opening quote, one huge line) is refused with
the file, the row and what is wrong (a fuzz trial: ``_csv.Error: field larger than field limit`` tracebacks)."""

from __future__ import annotations

import pytest

from planner.calibration.measurements import load_measurements, load_plan_targets
from planner.calibration.parameters import CalibrationError
from planner.profiles.hitch import load_profile

HEADER = "pose,lift_counts,tilt_counts,top_counts,left_counts,right_counts,x,z,roll,pitch\n"
ROW = "p{k},63,413,47,313,222,-0.05,-0.18,-0.03,0.07\n"


def test_a_stray_quote_in_the_first_label_names_the_row_and_line(tmp_path):
    f = tmp_path / "m.csv"
    rows = "".join(ROW.format(k=k) for k in range(2, 5000))  # about 230 KB after the stray quote
    f.write_text(HEADER + '"' + ROW.format(k=1) + rows)
    with pytest.raises(CalibrationError) as ei:
        load_measurements(f, load_profile())
    assert str(ei.value).startswith(f'{f} row 1 (line 2): a quoted field never ends (a stray " ?; it ran on to line ')


def test_one_huge_line_names_its_row_and_line(tmp_path):
    f = tmp_path / "m.csv"
    f.write_text(HEADER + ROW.format(k=1) + "1" * 5_000_000 + "\n")
    with pytest.raises(CalibrationError) as ei:
        load_measurements(f, load_profile())
    assert str(ei.value) == f"{f} row 2 (line 3): a cell longer than 131072 characters (not a CSV file of this kind?)"


def test_a_stray_quote_in_the_header_names_the_header(tmp_path):
    f = tmp_path / "m.csv"
    f.write_text('"' + HEADER + "".join(ROW.format(k=k) for k in range(5000)))
    with pytest.raises(CalibrationError) as ei:
        load_measurements(f, load_profile())
    assert str(ei.value).startswith(f'{f} row 0 (the header, line 1): a quoted field never ends (a stray " ?;')


def test_the_plan_file_reader_names_the_row_too(tmp_path):
    f = tmp_path / "plan.csv"
    row = "p{k},0.1,-0.2,0.0,0.0\n"
    f.write_text(
        "pose,target_x,target_z,target_roll,target_pitch\n"
        + row.format(k=1)
        + '"'
        + "".join(row.format(k=k) for k in range(2, 8000))
    )
    with pytest.raises(CalibrationError) as ei:
        load_plan_targets(f)
    assert str(ei.value).startswith(f'plan file {f} row 2 (line 3): a quoted field never ends (a stray " ?;')


def test_left_and_right_points_swapped_name_the_row_and_the_columns(tmp_path):
    """A commissioning trial: a --points file with L_* and R_* swapped ended in "the fit ends where the mechanism
    cannot close (… at actuators [0.16607, 0.614526, …] …)" naming no row or column. The left ball lies at +x."""
    f = tmp_path / "m.csv"
    head = HEADER.strip() + ",L_x,L_y,L_z,R_x,R_y,R_z\n"
    good = "p1,63,413,47,313,222,-0.05,-0.18,-0.03,0.07,0.39,0.93,-0.2,-0.46,0.92,-0.17\n"
    swapped = "p2,63,413,47,313,222,-0.05,-0.18,-0.03,0.07,-0.46,0.92,-0.17,0.39,0.93,-0.2\n"
    f.write_text(head + good + swapped)
    with pytest.raises(CalibrationError) as ei:
        load_measurements(f, load_profile())
    text = str(ei.value)
    assert text.startswith(f"{f} row 2 (line 3), columns L_x, R_x: L_x = -0.46 m is not left of R_x = 0.39 m"), text
    assert "are the L and R points swapped" in text
    f.write_text(head + good)
    assert load_measurements(f, load_profile()).n_rows == 1
