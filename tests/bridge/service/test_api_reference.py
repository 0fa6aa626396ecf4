"""docs/api.md's request table is the service's request schemas (it cannot drift), and every key has a summary."""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge.service.api_reference import BEGIN, END, KEY_SUMMARY, main, render_requests, replace_generated
from bridge.service.schemas import REQUESTS

DOC = Path(__file__).resolve().parents[3] / "docs" / "api.md"


def test_the_doc_holds_exactly_the_generated_table():
    text = DOC.read_text(encoding="utf-8")
    a, b = text.index(BEGIN), text.index(END) + len(END)
    assert text[a:b] == render_requests(), (
        "regenerate: .venv/bin/python -m bridge.service.api_reference --write docs/api.md"
    )


def test_every_key_has_a_row_and_a_summary_and_nothing_else_is_listed():
    assert set(KEY_SUMMARY) == set(REQUESTS)
    table = render_requests()
    for key in REQUESTS:
        assert f"| `{key}` |" in table
    assert table.count("\n| `") == len(REQUESTS)


def test_a_field_s_range_unit_default_and_requiredness_come_from_the_schema():
    table = render_requests()
    goto = next(line for line in table.splitlines() if line.startswith("| `goto` |"))
    assert "`speed_scale`: number [0.05, 1] (default 1)" in goto
    assert "`deadline_ms`: integer [1, 60000] ms (default 1000)" in goto
    assert "`goal`: {`x`: number [-1, 1] m" in goto and "(**required**)" in goto
    jog = next(line for line in table.splitlines() if line.startswith("| `jog` |"))
    assert "`ttl_ms`: number (0, 5000] ms" in jog and "`vroll`: number [-1, 1] rad/s" in jog
    sp = next(line for line in table.splitlines() if line.startswith("| `track/setpoint` |"))
    assert "`velocity`: {`x`: number [-1, 1] m/s" in sp  # a velocity's unit per second


def test_writing_replaces_only_the_generated_part(tmp_path):
    doc = tmp_path / "api.md"
    doc.write_text(f"head\n{BEGIN}\nOLD-TABLE\n{END}\ntail\n", encoding="utf-8")
    assert main(["--write", str(doc)]) == 0
    text = doc.read_text(encoding="utf-8")
    assert text.startswith("head\n") and text.endswith("\ntail\n") and "OLD-TABLE" not in text
    with pytest.raises(ValueError, match="no generated part"):
        replace_generated("no markers", render_requests())
    assert main(["--write", str(tmp_path / "missing.md")]) == 2


def test_a_nested_object_says_which_of_its_fields_are_required():
    """``implements/define``'s headland is a full pose, rendered like goto's partial goal: a fleet integrator sent
    ``{"z": 0.28}`` and got "field 'headland.x' is required". The table now says so; goto's goal stays partial."""
    table = render_requests()
    assert "`headland`: {`x`: number [-1, 1] m (**required**), `z`: number [-2, 2] m (**required**)" in table
    assert "`goal`: {`x`: number [-1, 1] m, `z`" in table
