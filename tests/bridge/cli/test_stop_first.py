"""``hitch stop`` is real-time before the command line is imported (bridge.cli): a field trial measured 7–10 s
for ``hitch stop`` on a loaded computer, the imports at ordinary priority (2.3–3.2 s with four busy processes on
two cores, side by side, /tmp-scratch bench; 0.8 s after)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.integration.service_process import ROOT

_PROBE = """
import os, sys
seen = {}
def hook(event, args):
    if event == "import" and args[0] == "bridge.cli.main" and "policy" not in seen:
        seen["policy"] = os.sched_getscheduler(0)
sys.addaudithook(hook)
sys.argv = ["hitch", *sys.argv[1:]]
import bridge.cli
print(seen["policy"] == os.SCHED_FIFO)
"""


def _fifo_permitted() -> bool:
    code = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 0


def _policy_at_import(*argv: str) -> str:
    out = subprocess.run([sys.executable, "-c", _PROBE, *argv], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler") or not _fifo_permitted(), reason="SCHED_FIFO not permitted")
def test_hitch_stop_is_real_time_before_the_command_line_is_imported_and_nothing_else_is():
    assert _policy_at_import("stop", "--connect", "tcp/127.0.0.1:1") == "True"
    assert _policy_at_import("state") == "False"
    assert _policy_at_import() == "False"
