"""Numbers on the command line are plain ASCII decimals, and what the CLI prints about them is exact.

A fuzz trial: ``hitch ik --z=１`` (a full-width digit) and ``hitch plan --to z=1_0`` were taken as 1 and 10
(Python's ``float()`` reads other scripts' digits and ``_`` separators; the track CSV reader and the service
refuse them); the roll limit was shown rounded (``±1.571 rad`` for 1.5708, which looked inside it); a failed
baseline IK printed ``residual inf``; ``hitch replay /dev/zero`` said the file "does not exist".
"""

from __future__ import annotations

import math

import pytest

from bridge.cli.main import main


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("bad", ["１", "1_0", "٣", "0x10", "1,5"])
def test_a_number_that_is_not_plain_ascii_is_refused_naming_the_option(capsys, bad):
    code, _, err = _run(capsys, "ik", "--x=0.02", f"--z={bad}", "--roll=0", "--pitch=0")
    assert code == 2 and "--z must be" in err and repr(bad) in err, err
    if "," not in bad:  # --to splits its pairs at commas
        code, _, err = _run(capsys, "plan", "--to", f"z={bad}")
        assert code == 2 and "z must be" in err and repr(bad) in err, err


@pytest.mark.parametrize("good", ["0.1", "+0.1", " 0.1 ", ".1", "1e-1", "1E-1", "10.", "-0"])
def test_plain_numbers_are_taken(capsys, good):
    code, out, err = _run(capsys, "ik", "--x=0", f"--z={good}", "--roll=0", "--pitch=0", "--json")
    assert code in (0, 1) and "must be" not in err, err


def test_the_roll_limit_is_shown_exactly_enough_to_see_the_value_is_beyond_it(capsys):
    code, _, err = _run(capsys, "ik", "--x=0.02", "--z=0.2", "--roll=1.5708", "--pitch=0")
    assert code != 0 and f"±{math.pi / 2:.7g} rad" in err, err
    assert "±1.571 rad" not in err


def test_a_failed_baseline_prints_no_infinite_residual(capsys):
    code, out, _ = _run(capsys, "ik", "--method", "geometric", "--x=5", "--z=0.2", "--roll=0.01", "--pitch=0")
    assert code == 1 and "pose - target: none (no solution)" in out and "inf" not in out, out


def test_replay_of_a_device_says_it_is_no_log_file(capsys):
    code, _, err = _run(capsys, "replay", "/dev/zero")
    assert code != 0 and "is not a regular file" in err and "does not exist" not in err, err


def test_a_service_key_above_every_table_names_its_table(tmp_path):
    """A fuzz trial: ``control_rate = 50`` at the top of a service config said "unknown section [control_rate]"."""
    from bridge.service.config import ServiceConfigError, load_service_config

    f = tmp_path / "service.toml"
    f.write_text("control_rate = 50\n")
    with pytest.raises(ServiceConfigError, match=r"control_rate is a key of \[hitch\]: put it under that table"):
        load_service_config(f)


def test_lines_save_says_geojson_must_be_an_object():
    import json

    from bridge.service.schemas import RequestError, parse_request

    with pytest.raises(RequestError, match=r"geojson = 'x' must be a GeoJSON object \(LineString, Feature or"):
        parse_request("lines/save", json.dumps({"name": "l1", "geojson": "x"}))
