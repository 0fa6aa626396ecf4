"""A scenario's speed or terrain CSV the CSV reader cannot read is refused naming the file and line (a fuzz
trial: ``_csv.Error: field larger than field limit`` as a traceback)."""

from __future__ import annotations

import pytest

from bridge.sim.scenario import ScenarioError, load_scenario


def _scenario(tmp_path, csv_text: str):
    (tmp_path / "speed.csv").write_text(csv_text)
    f = tmp_path / "s.toml"
    f.write_text('schema_version = 1\nname = "s"\nduration_s = 10.0\n[speed]\ncsv = "speed.csv"\n')
    return f


def test_a_stray_quote_names_the_file_and_line(tmp_path):
    f = _scenario(tmp_path, 'time_s,speed_m_s\n0,1.0\n"60,1.0\n' + "".join(f"{60 + k},1.0\n" for k in range(1, 30000)))
    with pytest.raises(ScenarioError) as ei:
        load_scenario(f)
    assert f'{tmp_path / "speed.csv"} line 3: a quoted field never ends (a stray " ?; it ran on to line ' in str(
        ei.value
    )


def test_one_huge_line_names_the_file_and_line(tmp_path):
    f = _scenario(tmp_path, "time_s,speed_m_s\n0,1.0\n" + "1" * 5_000_000 + "\n")
    with pytest.raises(ScenarioError) as ei:
        load_scenario(f)
    assert str(ei.value) == (
        f"{tmp_path / 'speed.csv'} line 3: a cell longer than 131072 characters (not a CSV file of this kind?)"
    )


def test_a_semicolon_file_from_a_european_spreadsheet_is_named_as_such(tmp_path):
    """A technician's speed file saved by a spreadsheet with decimal commas was refused as a header
    'time_s;speed_m_s' that "must be time_s,speed_m_s", which does not say what to change (hitch track's and the
    calibration reader's say so)."""
    f = _scenario(tmp_path, "time_s;speed_m_s\n0;1,6\n10;1,6\n")
    with pytest.raises(ScenarioError) as ei:
        load_scenario(f)
    assert str(ei.value) == (
        f"{tmp_path / 'speed.csv'} line 1: the header is separated by semicolons (a spreadsheet's CSV with decimal "
        "commas?); save it as CSV with commas between cells and decimal points: time_s,speed_m_s"
    )


def test_a_csv_larger_than_a_scenario_may_be_is_refused_before_it_is_read(tmp_path):
    """A 51 MB scenario CSV was read into 712 MB of memory (a field trial); beyond 32 MiB it is refused naming the
    file, its size and the limit, before reading."""
    from bridge.sim.scenario import MAX_CSV_BYTES

    f = _scenario(tmp_path, "time_s,speed_m_s\n0,1.0\n10,1.0\n")
    with (tmp_path / "speed.csv").open("ab") as fh:  # a sparse tail: the size without writing 32 MiB
        fh.truncate(MAX_CSV_BYTES + 1)
    with pytest.raises(ScenarioError) as ei:
        load_scenario(f)
    assert (
        str(ei.value)
        == f"CSV file {tmp_path / 'speed.csv'}: 32.0 MiB, larger than this kind of file may be (32 MiB allowed)"
    )
