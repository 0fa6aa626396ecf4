"""Ctrl-C while the ``hitch`` command line is still loading its modules (about 2 s on a loaded computer) ends
with one line and status 130, not a Python traceback (a field trial). The interrupt is raised deterministically
where the signal lands in practice: inside the import of the command line."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.integration.service_process import ROOT

_INTERRUPTED_IMPORT = """
import builtins, runpy, sys
real = builtins.__import__
def interrupted(name, *args, **kwargs):
    if name == "bridge.cli.main" and "bridge.cli.main" not in sys.modules:
        raise KeyboardInterrupt
    return real(name, *args, **kwargs)
builtins.__import__ = interrupted
sys.argv = ["hitch", "--help"]
runpy.run_module("bridge.cli", run_name="__main__")
"""


@pytest.mark.parametrize("entry", ["module", "script"])
def test_ctrl_c_while_the_command_line_loads_says_so_without_a_traceback(entry):
    code = (
        _INTERRUPTED_IMPORT
        if entry == "module"
        else _INTERRUPTED_IMPORT.replace(
            'runpy.run_module("bridge.cli", run_name="__main__")', "from bridge.cli import main\nsys.exit(main())"
        )
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert "Traceback" not in out.stderr, out.stderr
    assert out.returncode == 130 and "hitch: interrupted while starting" in out.stderr
