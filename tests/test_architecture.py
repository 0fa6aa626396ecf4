"""The house rules, read from the code's own imports (every ``import``, also inside functions).

* Layers run one way: ``bridge.cli`` → ``bridge.service`` → ``bridge.web``, ``bridge.link``, ``bridge.sim`` →
  ``bridge.isobus`` → ``planner``; ``bridge.sim`` may use ``bridge.link`` (the closed-loop rig wires a link to the
  simulated ECU), ``bridge.link`` never uses ``bridge.sim`` (the planner side runs with no simulator present).
* Nothing outside ``bridge.cli`` imports ``bridge.cli``; ``planner`` imports nothing of ``bridge``.
* No package imports the ``planner`` or ``bridge`` facade (their ``__init__``) from inside: modules import from the
  defining module, so the facades can re-export without cycles.
* No cycles between packages (folders).
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("planner", "bridge")

#: bridge sub-package -> the bridge sub-packages it may import (planner is always allowed)
ALLOWED: dict[str, set[str]] = {
    "cli": {"cli", "service", "web", "link", "sim", "isobus"},
    "service": {"service", "web", "link", "sim", "isobus"},
    "web": {"web"},
    "sim": {"sim", "link", "isobus"},
    "link": {"link", "isobus"},
    "isobus": {"isobus"},
}


def _module_name(path: Path) -> tuple[str, bool]:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    is_pkg = parts[-1] == "__init__"
    return ".".join(parts[:-1] if is_pkg else parts), is_pkg


@cache
def project_imports() -> dict[str, frozenset[str]]:
    """Module → the project modules (or packages) it imports, relative imports resolved."""
    out: dict[str, frozenset[str]] = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            name, is_pkg = _module_name(path)
            found: set[str] = set()
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    found.update(a.name for a in node.names)
                elif isinstance(node, ast.ImportFrom):
                    if node.level:
                        base = name.split(".") if is_pkg else name.split(".")[:-1]
                        base = base[: len(base) - node.level + 1]
                        mod = ".".join(base + ([node.module] if node.module else []))
                    else:
                        mod = node.module or ""
                    found.add(mod)
                    found.update(f"{mod}.{a.name}" for a in node.names if _is_module(f"{mod}.{a.name}"))
            out[name] = frozenset(m for m in found if m.split(".")[0] in PACKAGES)
    return out


def _is_module(dotted: str) -> bool:
    p = ROOT.joinpath(*dotted.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def _package_of(module: str) -> str:
    """The folder a module lives in (a package ``__init__`` is its own folder)."""
    p = ROOT.joinpath(*module.split("."))
    return module if (p / "__init__.py").is_file() else module.rsplit(".", 1)[0]


def _bridge_layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "bridge" and len(parts) > 1 else None


def test_the_import_scan_sees_the_code():
    imports = project_imports()
    assert len(imports) > 80
    assert "bridge.link.can_link" in imports["bridge.sim.rig"]  # a known edge
    assert any(m.startswith("planner.model") for m in imports["bridge.link.state"])


def layer_violations(imports: dict[str, frozenset[str]]) -> list[str]:
    """Every import that runs against the layers, as ``"module -> imported (why)"``."""
    bad = []
    for mod, deps in imports.items():
        layer = _bridge_layer(mod)
        for dep in deps:
            if mod.startswith("planner") and dep.startswith("bridge"):
                bad.append(f"{mod} -> {dep} (planner imports nothing of bridge)")
            elif layer is not None and dep.startswith("bridge."):
                target = _bridge_layer(dep)
                if target not in ALLOWED[layer]:
                    bad.append(f"{mod} -> {dep} ({layer} may use {sorted(ALLOWED[layer])})")
            if (dep == "bridge.cli" or dep.startswith("bridge.cli.")) and not mod.startswith("bridge.cli"):
                bad.append(f"{mod} -> {dep} (nothing outside bridge.cli imports it)")
    return sorted(set(bad))


def test_layers_run_one_way():
    bad = layer_violations(project_imports())
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize(
    "edge",
    [
        ("bridge.link.state", "bridge.sim.ecu"),  # the planner side needs no simulator
        ("bridge.service.server", "bridge.cli.sim"),  # the service must not take its runner from the CLI
        ("bridge.isobus.codec", "bridge.link.state"),
        ("planner.model.kinematics", "bridge.isobus.codec"),
        ("bridge.web.server", "bridge.service.api"),
    ],
)
def test_a_wrong_way_import_is_reported(edge):
    mod, dep = edge
    imports = dict(project_imports())
    imports[mod] = imports.get(mod, frozenset()) | {dep}
    assert any(v.startswith(f"{mod} -> {dep}") for v in layer_violations(imports))


def test_nothing_outside_cli_imports_cli():
    bad = [
        f"{m} -> {d}"
        for m, d_ in project_imports().items()
        for d in d_
        if (d == "bridge.cli" or d.startswith("bridge.cli.")) and not m.startswith("bridge.cli")
    ]
    assert not bad, "\n".join(bad)


def test_no_module_imports_a_facade():
    bad = [
        f"{m} -> {d}"
        for m, d_ in project_imports().items()
        for d in d_
        if d in PACKAGES and m.split(".")[0] == d and m != d
    ]
    assert not bad, "\n".join(bad)


def _package_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for mod, deps in project_imports().items():
        src = _package_of(mod)
        graph.setdefault(src, set())
        for dep in deps:
            dst = _package_of(dep) if _is_module(dep) else dep
            # a package __init__ re-exporting its own sub-packages is the package itself, not a cycle
            if dst != src and not dst.startswith(src + ".") and dst not in PACKAGES:
                graph[src].add(dst)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of the directed graph as a node list, or None (iterative DFS, colours)."""
    colour = dict.fromkeys(graph, 0)
    for start in graph:
        if colour[start]:
            continue
        stack = [(start, iter(sorted(graph[start])))]
        path = [start]
        colour[start] = 1
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                colour[node] = 2
                stack.pop()
                path.pop()
            elif colour.get(nxt, 0) == 1:
                return path[path.index(nxt) :] + [nxt]
            elif colour.get(nxt, 0) == 0:
                colour[nxt] = 1
                path.append(nxt)
                stack.append((nxt, iter(sorted(graph.get(nxt, ())))))
    return None


def test_no_cycles_between_packages():
    cycle = find_cycle(_package_graph())
    assert cycle is None, " -> ".join(cycle)


@pytest.mark.parametrize(
    "graph, cyclic",
    [
        ({"a": {"b"}, "b": {"c"}, "c": set()}, False),
        ({"a": {"b"}, "b": {"c"}, "c": {"a"}}, True),
        ({"a": {"a"}}, True),
        ({"a": {"b", "c"}, "b": {"c"}, "c": set()}, False),
    ],
)
def test_cycle_finder_on_known_graphs(graph, cyclic):
    assert (find_cycle(graph) is not None) == cyclic


def test_every_module_is_named_in_the_architecture_table_of_its_folder():
    """A newcomer's trial: docs/architecture.md's "What each folder does" left out 24 modules (track.py, where the
    link checks a reference, the root error …). Each module's file name is in the row of its nearest folder
    (``planner/`` for planner's own files)."""
    doc = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    rows: dict[str, str] = {}
    for line in doc.splitlines():
        if line.startswith("| `") and "/` " in line.split("|")[1]:
            folder = line.split("`")[1]
            rows[folder] = line
    missing = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if path.name in ("__init__.py", "__main__.py"):
                continue
            rel = path.relative_to(ROOT).as_posix()
            folders = [f for f in rows if rel.startswith(f)]
            if not folders or path.name not in rows[max(folders, key=len)]:
                missing.append(rel)
    assert not missing, f"not named in docs/architecture.md's folder table: {missing}"
