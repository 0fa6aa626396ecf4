"""``hitch serve`` with a profile, category or implement that does not exist, run as a user would (a real
subprocess of the console script): one line ``hitch: error: …`` naming the setting and what exists, exit
status 2, and no traceback from any process (the planning workers once printed one each).

Truth: the profiles shipped with the package (``thesis-t132``, its categories; its tractor profile
``tractor-6t`` and that profile's implements).
"""

import subprocess
import sys
from pathlib import Path

import pytest

HITCH = [str(Path(sys.executable).with_name("hitch"))]


@pytest.mark.parametrize(
    "flags, names",
    [
        (["--profile", "nosuch"], ["profile 'nosuch' not found", "built-in profiles: thesis-t132"]),
        (["--category", "9"], ["category '9' is not in profile 'thesis-t132'", "allowed: 1N, 1, 2N, 2"]),
        (
            ["--implement", "nosuch"],
            ["implement 'nosuch' is not in tractor profile 'tractor-6t'", "allowed: cat2-spreader-400"],
        ),
    ],
    ids=["profile", "category", "implement"],
)
def test_serve_with_a_setting_that_does_not_exist_prints_one_line_and_no_traceback(tmp_path, flags, names):
    r = subprocess.run(
        HITCH + ["serve", "--data-dir", str(tmp_path / "data"), *flags],
        capture_output=True,
        text=True,
        timeout=120,
        stdin=subprocess.DEVNULL,
    )
    assert r.returncode == 2, r.stderr[-3000:]
    assert "Traceback" not in r.stderr, r.stderr[-3000:]
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hitch: error: "), r.stderr[-3000:]
    for name in names:
        assert name in lines[0]
