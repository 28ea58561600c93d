"""The package's import structure: no package imports one that imports it back, production code
never imports a fixture (phonepose.testing), and the pipeline knows no session format (it imports
neither phonepose.session nor phonepose.schemas: the scheduler hands it plain values).

Every import statement counts, also those inside functions and under ``if TYPE_CHECKING:``: a
local import still ties the two packages together, it only hides the tie from a reader.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import phonepose

ROOT = Path(phonepose.__file__).parent
FIXTURES = "phonepose.testing"
FORMAT_FREE = "phonepose.pipeline"
FORMATS = ("phonepose.session", "phonepose.schemas")


def _modules() -> dict[str, tuple[Path, bool]]:
    """Module name -> (file, is a package's __init__), generated protobuf code left out."""
    out = {}
    for path in ROOT.rglob("*.py"):
        if path.name.endswith("_pb2.py"):
            continue
        parts = ["phonepose", *path.relative_to(ROOT).with_suffix("").parts]
        is_pkg = parts[-1] == "__init__"
        out[".".join(parts[:-1] if is_pkg else parts)] = (path, is_pkg)
    return out


MODULES = _modules()


def _imports(name: str) -> set[str]:
    """The phonepose modules ``name`` imports (``from a.b import c`` counts a.b, and a.b.c if a module)."""
    path, is_pkg = MODULES[name]
    package = name if is_pkg else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([node.module] if node.module else []))
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names)
    return {m for m in found if m in MODULES or m.startswith(FORMATS)}   # generated _pb2 modules too


def _package(name: str) -> str:
    """The package a module belongs to; a top-level module (phonepose.geometry) is its own node."""
    path, is_pkg = MODULES[name]
    if is_pkg or name.count(".") == 1:
        return name
    return name.rsplit(".", 1)[0]


def _package_graph() -> dict[str, dict[str, list[str]]]:
    """package -> imported package -> the module imports that make the edge (for the message)."""
    graph: dict[str, dict[str, list[str]]] = defaultdict(lambda: defaultdict(list))
    for name in MODULES:
        for target in _imports(name) & MODULES.keys():
            a, b = _package(name), _package(target)
            if a != b:
                graph[a][b].append(f"{name} -> {target}")
    return graph


def _cycles(graph) -> list[list[str]]:
    """The strongly connected components with more than one package (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(set(graph) | {w for e in graph.values() for w in e}):
        if v not in index:
            visit(v)
    return out


def test_the_walk_sees_the_packages_and_their_imports():
    graph = _package_graph()
    assert {"phonepose.playback", "phonepose.pipeline", "phonepose.session", "phonepose.geometry"} <= set(MODULES)
    assert "phonepose.session" in graph["phonepose.playback"]          # the scheduler reads sessions
    assert "phonepose.geometry" in graph["phonepose.pipeline"]


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b": []}, "b": {"c": []}, "c": {"a": []}, "d": {"a": []}}) == [["a", "b", "c"]]


def test_no_package_imports_one_that_imports_it_back():
    graph = _package_graph()
    problems = []
    for component in _cycles(graph):
        edges = [e for a in component for b in component for e in graph.get(a, {}).get(b, [])[:2]]
        problems.append(f"{' <-> '.join(component)}: {'; '.join(edges)}")
    assert not problems, "import cycles between packages:\n" + "\n".join(problems)


def test_no_production_module_imports_a_fixture():
    bad = sorted(f"{name} imports {target}" for name in MODULES if not name.startswith(FIXTURES)
                 for target in _imports(name) if target == FIXTURES or target.startswith(FIXTURES + "."))
    assert not bad, "\n".join(bad)


def _within(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def test_the_pipeline_imports_no_session_format():
    assert any(_within(name, FORMAT_FREE) for name in MODULES)
    bad = sorted(f"{name} imports {target}" for name in MODULES if _within(name, FORMAT_FREE)
                 for target in _imports(name) if any(_within(target, f) for f in FORMATS))
    assert not bad, "the pipeline must not know the session's format:\n" + "\n".join(bad)


def test_the_format_check_sees_a_generated_module(tmp_path, monkeypatch):
    """An import of phonepose_pb2 (left out of MODULES) still counts, as a function-local one does."""
    src = tmp_path / "probe.py"
    src.write_text("def f():\n    from phonepose.schemas import phonepose_pb2 as pb\n    from phonepose.session import codec\n")
    monkeypatch.setitem(MODULES, "phonepose.pipeline.probe", (src, False))
    assert _imports("phonepose.pipeline.probe") >= {"phonepose.schemas.phonepose_pb2", "phonepose.session.codec"}
