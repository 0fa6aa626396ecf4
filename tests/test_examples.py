"""Every script in ``examples/`` runs to the end as a user would run it (its own interpreter).

Truth: the exit status and the output of the scripts themselves; each script checks what it
shows only by printing it, so a run that ends with status 0 and prints SI values passes.
"""

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("[0-9][0-9]_*.py"))
#: closed loop over CAN and a whole service with Zenoh: a few seconds each
SLOW = {"07_closed_loop_sim.py", "08_service_client.py", "10_track_stream.py"}


PARAMS = [pytest.param(p, id=p.stem, marks=[pytest.mark.slow] if p.name in SLOW else []) for p in EXAMPLES]


def test_the_examples_are_numbered_and_use_the_public_api():
    names = [p.name for p in EXAMPLES]
    assert len(names) >= 6
    assert [int(n[:2]) for n in names] == list(range(1, len(names) + 1))
    assert set(SLOW) <= set(names)
    for path in EXAMPLES:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        assert ast.get_docstring(tree), f"{path.name} has no docstring"
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in ("planner", "bridge"):
                # the public API: a package facade (planner, planner.arm, bridge), never the CLI
                assert (ROOT.joinpath(*node.module.split(".")) / "__init__.py").is_file(), (path.name, node.module)
                assert not node.module.startswith("bridge.cli"), f"{path.name} imports the CLI"


@pytest.mark.parametrize("path", PARAMS)
def test_example_runs(path):
    r = subprocess.run([sys.executable, str(path)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, f"{path.name} failed:\n{r.stdout}\n{r.stderr}"
    assert r.stdout.strip(), f"{path.name} printed nothing"
    assert re.search(r"[\d)\]] (m|mm|rad|mrad|s|N|J|µs|Hz|counts)\b", r.stdout), f"{path.name} prints no SI values"
