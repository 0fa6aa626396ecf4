"""A profile that names its tractor profile by a relative path, written by a command into another folder:
the path is rewritten for the folder the file goes to, and a text that does not load there is not written.

A commissioning engineer's report: ``calibrate geometry --profile prof/mine.toml --out prof/cal2.toml`` wrote
``tractor_profile = "prof/my-tractor.toml"`` (relative to the working folder), which the loader took from the
file's folder (``prof/prof/my-tractor.toml``), and left that unloadable file on disk; ``calibrate sensors`` and
``sim perturb`` copied the path as it was into files in other folders.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from planner.profiles.hitch import ProfileError, load_profile, tractor_profile_for, write_profile_text
from planner.profiles.loader import builtin_profiles
from tests.helpers import profiles_with_own_tractor


@pytest.fixture
def own_tractor(tmp_path, monkeypatch):
    """prof/mine.toml naming prof/my-tractor.toml as "my-tractor.toml" (profiles_with_own_tractor); cwd = tmp."""
    profiles_with_own_tractor(tmp_path)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_a_tractor_path_is_written_relative_to_the_new_file(own_tractor):
    assert "tractor-6t" in builtin_profiles("tractors")
    assert tractor_profile_for("tractor-6t", "out") == "tractor-6t"  # a built-in name stays
    assert tractor_profile_for("prof/my-tractor.toml", "out") == os.path.join("..", "prof", "my-tractor.toml")
    assert tractor_profile_for("my-tractor.toml", "out", relative_to="prof") == os.path.join(
        "..", "prof", "my-tractor.toml"
    )
    assert tractor_profile_for("prof/my-tractor.toml", "prof") == "my-tractor.toml"
    absolute = tractor_profile_for("prof/my-tractor.toml", None)
    assert Path(absolute).is_absolute() and Path(absolute) == own_tractor / "prof" / "my-tractor.toml"


def test_a_profile_text_is_written_only_where_it_loads(own_tractor):
    good = (own_tractor / "prof" / "mine.toml").read_text()
    with pytest.raises(ProfileError) as exc:
        write_profile_text("out/copy.toml", good)  # my-tractor.toml is not beside out/copy.toml
    assert "out/copy.toml was not written" in str(exc.value) and "my-tractor.toml" in str(exc.value)
    assert sorted(p.name for p in (own_tractor / "out").iterdir()) == []  # nothing left behind
    (own_tractor / "out" / "copy.toml").write_text("kept")
    with pytest.raises(ProfileError):
        write_profile_text("out/copy.toml", good)
    assert (own_tractor / "out" / "copy.toml").read_text() == "kept"  # an old file stays as it was
    fixed = good.replace('tractor_profile = "my-tractor.toml"', 'tractor_profile = "../prof/my-tractor.toml"')
    prof = write_profile_text("out/copy.toml", fixed)
    assert prof.stability.tractor_profile == os.path.join("out", "..", "prof", "my-tractor.toml")
    assert load_profile("out/copy.toml") == prof
    with pytest.raises(ProfileError, match=r"must end in \.toml"):
        write_profile_text("out/copy.txt", fixed)


def test_a_directory_given_for_a_profile_is_named_a_directory(tmp_path):
    """A new user's trial: ``--profile /tmp`` said "profile file /tmp does not exist"."""
    with pytest.raises(ProfileError, match=rf"profile file {re.escape(str(tmp_path))} is a directory, not a file"):
        load_profile(tmp_path)
    folder = tmp_path / "mine.toml"  # a folder named like a profile file
    folder.mkdir()
    with pytest.raises(ProfileError, match="is a directory, not a file"):
        load_profile(folder)
    with pytest.raises(ProfileError, match=r"profile file \S+missing\.toml does not exist"):
        load_profile(tmp_path / "missing.toml")
