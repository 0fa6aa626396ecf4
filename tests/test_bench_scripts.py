"""Every benchmark starts as the docs run it (``.venv/bin/python bench/NAME.py``): run as a script,
``bench/`` is ``sys.path[0]`` and the repository root is not, so an ``import bench._common`` without
its script fallback fails there even though the tests (which import ``bench`` as a package) pass.
``--help`` loads each script's module-level imports and its argument parser, and runs nothing; an
import inside a function is checked from the source."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for p in (ROOT / "bench").glob("*.py") if not p.name.startswith("_"))


def test_the_bench_folder_has_scripts():
    assert len(SCRIPTS) >= 10


@pytest.mark.slow
def test_every_bench_script_starts_from_another_folder(tmp_path):
    procs = {
        p.name: subprocess.Popen(
            [sys.executable, str(p), "--help"],
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for p in SCRIPTS
    }
    failed = {}
    for name, proc in procs.items():
        out, _ = proc.communicate(timeout=120)
        if proc.returncode != 0 or "usage:" not in out:
            failed[name] = out[-800:]
    assert not failed, failed


def _package_imports_without_fallback(tree: ast.AST) -> list[int]:
    """Lines of ``import bench…`` / ``from bench… import`` outside a ``try`` that catches ImportError."""
    guarded: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Try) and any(
            isinstance(h.type, ast.Name) and h.type.id in ("ImportError", "ModuleNotFoundError") for h in node.handlers
        ):
            guarded.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    lines = []
    for node in ast.walk(tree):
        names = (
            [node.module or ""]
            if isinstance(node, ast.ImportFrom)
            else [a.name for a in node.names]
            if isinstance(node, ast.Import)
            else []
        )
        if any(n == "bench" or n.startswith("bench.") for n in names) and id(node) not in guarded:
            lines.append(node.lineno)
    return lines


def test_no_bench_script_imports_the_bench_package_without_its_script_fallback():
    bad = {p.name: _package_imports_without_fallback(ast.parse(p.read_text())) for p in SCRIPTS}
    assert not {k: v for k, v in bad.items() if v}, bad


def test_the_import_check_finds_an_unguarded_import_in_a_function():
    src = "def main():\n    from bench._common import free_port\n"
    assert _package_imports_without_fallback(ast.parse(src)) == [2]
    ok = "try:\n    from bench._common import free_port\nexcept ImportError:\n    from _common import free_port\n"
    assert _package_imports_without_fallback(ast.parse(ok)) == []
