"""``hitch profile show --profile FILE`` of a profile copy whose geometry does not close names the field, its
value and the range that loads, on one line without a class name (a user trial: a 1.9 m mast, a 1.9 m span and
a 0.2 m lower link were refused naming no field or no range; a restricted box out of reach said
"KinematicsError: lower links cannot reach …")."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import pytest

from bridge.cli import main

THESIS = (resources.files("planner") / "profiles" / "thesis-t132.toml").read_text()


def _profile(tmp_path: Path, old: str, new: str) -> Path:
    assert THESIS.count(old) == 1
    path = tmp_path / "mine.toml"
    path.write_text(THESIS.replace(old, new))
    return path


def _show(capsys, path: Path) -> str:
    assert main(["profile", "show", "--profile", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("hitch: error: ") and "Error:" not in err
    return err


@pytest.mark.parametrize(
    ("old", "new", "said"),
    [
        (
            "[implement.categories.2]\nspan = 0.825\nmast_height = 0.610",
            "[implement.categories.2]\nspan = 0.825\nmast_height = 1.9",
            "or implement.categories.2.mast_height = 1.9 m must be at most 0.9623 m (the masts the stroke holds",
        ),
        (
            "[implement.categories.2]\nspan = 0.825",
            "[implement.categories.2]\nspan = 1.9",
            "implement.categories.2.span = 1.9 m: the lower links cannot reach this span with lift and tilt at their "
            "neutrals (actuators.lift.neutral, actuators.tilt.neutral); with the other fields as given, "
            "implement.categories.2.span must be at most 1.7987 m (ISO 730",
        ),
        (
            "lower_link_length = 0.960 ",
            "lower_link_length = 0.2 ",
            "lower_link_length = 0.2 m (points on it are measured along it from its pivot): with the other fields "
            "as given, lower_link_length must be within (0.54, 3] m, or lift_rod_attachment and "
            "limiter_bracket_position within (0, 0.2) m",
        ),
    ],
    ids=["mast_height", "span", "lower_link_length"],
)
def test_the_trials_geometry_slips_name_the_field_the_value_and_its_range(tmp_path, capsys, old, new, said):
    assert said in _show(capsys, _profile(tmp_path, old, new))


def test_an_unreachable_restricted_box_names_the_cause_without_a_class_name(tmp_path, capsys):
    path = _profile(tmp_path, "x = [-0.060000, 0.060000]   # x:min top_link_yaw_max", "x = [-1.6, 1.6]   #")
    err = _show(capsys, path)
    assert "workspace.restricted.2 (x [-1.6, 1.6]," in err
    assert "pitch = -0.1 lower links cannot reach the implement at this pose (closure error" in err
    assert "KinematicsError" not in err
