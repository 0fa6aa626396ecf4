"""README.md: its "Python API" example runs as printed, and the paths it names exist.

Truth: the README text itself (the code block is extracted, not copied), the file tree and
the Makefile.
"""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def section(title: str) -> str:
    """The text of the ``## title`` section, up to the next ``## `` heading."""
    m = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", README, re.S | re.M)
    assert m, f"README has no section {title!r}"
    return m.group(1)


def python_api_example() -> str:
    m = re.search(r"^```python\n(.*?)^```", section("Python API"), re.S | re.M)
    assert m, "the Python API section has no python code block"
    return m.group(1)


def test_the_python_api_section_is_near_the_top():
    headings = re.findall(r"^## (.+)$", README, re.M)
    assert "Python API" in headings[:3]


def test_the_python_api_example_runs_and_prints_the_checked_plan():
    code = python_api_example()
    assert 6 <= len([ln for ln in code.splitlines() if ln.strip()]) <= 10
    assert "TrajectoryPlanner" in code and "Guard" in code
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert re.fullmatch(r"\d+\.\d\d s to x = 0\.030 m, z = 0\.250 m: ok\n", r.stdout), r.stdout


_PATH = re.compile(r"`((?:planner|bridge|tests|docs|bench|examples|\.ci)/[^`\s|]*)`")


def test_every_path_the_readme_names_exists():
    paths = {m.split("::")[0] for m in _PATH.findall(README)}
    assert len(paths) > 20
    missing = sorted(p for p in paths if not (ROOT / p).exists())
    assert not missing, f"README names paths that do not exist: {missing}"


def test_no_references_outside_the_repository_or_to_issue_numbers():
    assert "../" not in README
    assert not re.search(r"\bissue \d", README, re.I)


def test_the_make_targets_the_readme_names_exist():
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    for target in re.findall(r"^make (\w+)", section("Development"), re.M):
        assert re.search(rf"^{target}:", makefile, re.M), f"no make target {target!r}"
    lint = re.search(r"^lint:.*?(?=^\S)", makefile, re.S | re.M)
    assert lint and all(tool in lint.group(0) for tool in ("ruff check", "ruff format --check", "mypy"))
