"""``hitch track --from-file``: what the signal CSV reader says of files the CSV reader cannot read, of a
semicolon header and of a binary header, and its row limit (a fuzz trial: a traceback, no hint, 2.4 KB of
junk echoed, and 55 s and 1.7 GB for a 3-million-row file)."""

from __future__ import annotations

import pytest

from bridge.cli import track
from bridge.cli.errors import CLIError
from bridge.cli.track import read_signal_csv


def _refused(path) -> str:
    with pytest.raises(CLIError) as ei:
        read_signal_csv(path)
    return str(ei.value)


def test_a_stray_quote_names_the_line(tmp_path):
    f = tmp_path / "s.csv"
    f.write_text('t,z\n0,0.1\n"0.5,0.1\n' + "".join(f"{k},0.1\n" for k in range(1, 30000)))
    assert _refused(f).startswith(f'{f}: line 3: a quoted field never ends (a stray " ?; it ran on to line ')


def test_one_huge_line_names_the_line(tmp_path):
    f = tmp_path / "s.csv"
    f.write_text("t,z\n0,0.1\n" + "1" * 5_000_000 + "\n")
    assert _refused(f) == f"{f}: line 3: a cell longer than 131072 characters (not a CSV file of this kind?)"


def test_a_semicolon_header_is_said_as_the_calibration_reader_says_it(tmp_path):
    f = tmp_path / "s.csv"
    f.write_text("t;z\n0;0,1\n1;0,2\n")
    assert _refused(f) == (
        f"{f}: line 1: the header is separated by semicolons (a spreadsheet's CSV with decimal commas?); save it "
        "as CSV with commas between cells and decimal points"
    )


def test_a_binary_header_is_echoed_60_characters_at_most(tmp_path):
    f = tmp_path / "s.csv"
    junk = "".join(chr(c) for c in range(1, 128) if chr(c) not in ',"\r\n') * 20  # 2.4 KB, one cell
    f.write_text("t,z," + junk + "\n0,0.1,1\n")
    msg = _refused(f)
    assert msg == f"{f}: line 1, column 3: unknown column {repr(junk)[:60]}…; allowed: t, x, z, roll, pitch, " + (
        "v_x, v_z, v_roll, v_pitch (SI units)"
    )
    assert len(msg) < 170 + len(str(f))  # not the 2.4 KB


def test_a_file_of_more_rows_than_a_run_can_play_is_refused_naming_the_limit(tmp_path):
    assert track.MAX_SIGNAL_ROWS == 360_001  # 3600 s at 100 Hz, both ends
    f = tmp_path / "s.csv"
    rows = [f"{k / 100:.2f},0.1\n" for k in range(360_001)]
    f.write_text("t,z\n" + "".join(rows))
    sig = read_signal_csv(f)  # the most a run plays: accepted
    assert sig.t.shape == (360_001,) and sig.span_s == pytest.approx(3600.0)
    f.write_text("t,z\n" + "".join(rows) + "3600.01,0.1\n")
    assert _refused(f) == (
        f"{f}: line 360003: more than 360001 rows of values (allowed: at most 360001, 3600 s at 100 Hz, the "
        "longest run at the highest setpoint rate); play a part of the file, or resample it"
    )


def test_values_are_read_as_before(tmp_path):
    f = tmp_path / "s.csv"
    f.write_text("\ufeff# a comment\nt,z,v_z\n\n1.0,0.1,0.0\n1.5,0.12,0.04\n2.0,0.13,0.0\n")
    sig = read_signal_csv(f)
    assert sig.t.tolist() == [0.0, 0.5, 1.0]
    assert sig.positions["z"].tolist() == [0.1, 0.12, 0.13] and sig.velocities["z"].tolist() == [0.0, 0.04, 0.0]
    f.write_text("t,z\n0,0.1\n1,1_0\n")
    assert _refused(f).startswith(f"{f}: line 3, column 2 (z): not a number: '1_0'")
    f.write_text("t,z\n0,0.1\n1,5\n")
    assert _refused(f).startswith(f"{f}: line 3, column 2 (z): 5 m is outside")
    f.write_bytes(b"t,z\n0,0.1\n1,0.\xff\n")
    assert _refused(f) == f"--from-file {f}: not UTF-8 text (byte 14, line 3: 0xff); save it as UTF-8"
