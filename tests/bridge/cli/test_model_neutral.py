"""``hitch demo`` / ``hitch profile show`` flag a neutral pose beyond the strokes (a new user's trial: category 4
showed a neutral top link of 0.9728 m beside its 0.905 m stroke without a word)."""

import json

from bridge.cli import main

CAT4 = "the neutral pose of category 4 needs top = 0.9728 m, beyond its stroke 0.655..0.905 m (stroke:top:max)"


def test_profile_show_flags_a_neutral_top_link_beyond_its_stroke(capsys):
    assert main(["profile", "show", "--category", "4"]) == 0
    out = capsys.readouterr().out
    assert f"warning: {CAT4}: the hitch cannot take this pose" in out
    assert main(["profile", "show", "--category", "4", "--json"]) == 0
    warnings = json.loads(capsys.readouterr().out)["warnings"]
    assert len(warnings) == 1 and warnings[0].startswith(CAT4)


def test_demo_flags_it_too_and_a_category_within_its_strokes_has_no_warning(capsys):
    assert main(["demo", "--category", "4"]) == 0
    assert f"warning: {CAT4}" in capsys.readouterr().out
    assert main(["demo"]) == 0
    assert "warning" not in capsys.readouterr().out
    assert main(["profile", "show", "--category", "2", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == []
