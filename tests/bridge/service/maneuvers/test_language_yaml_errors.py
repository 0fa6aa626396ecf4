"""A maneuver script with a character YAML does not allow says the line and column (a fuzz trial: ``in
"<unicode string>", position 0``)."""

from __future__ import annotations

import pytest

from bridge.service.maneuvers.language import ManeuverError, parse_maneuver


@pytest.mark.parametrize(
    "text, expected",
    [
        (
            "\x00\x01steps: []\n",
            "script is not valid YAML at line 1, column 1: character U+0000 is not allowed (special characters are "
            "not allowed)",
        ),
        (
            "steps:\n  - goto: {z: 0.1}\n  - wait: 1\x07\n",
            "script is not valid YAML at line 3, column 12: character U+0007 is not allowed (special characters are "
            "not allowed)",
        ),
    ],
)
def test_a_character_yaml_does_not_allow_is_located_by_line_and_column(text, expected):
    with pytest.raises(ManeuverError) as ei:
        parse_maneuver(text)
    assert [e.to_json() for e in ei.value.errors] == [{"step": None, "message": expected}]


def test_a_syntax_error_keeps_its_line_and_column():
    with pytest.raises(ManeuverError) as ei:
        parse_maneuver("steps:\n  - goto: {z: 0.1\n")
    assert str(ei.value).startswith("script is not valid YAML at line 3, column 1: ")
