"""The layer diagram of docs/architecture.md, enforced: every project module imports only from its
own floor or those below, the floors form no cycle, no modules of one package import each other in
a loop, and a RApp package's code imports only the SDK and the ontology (so it runs from its package
alone on any Platform that offers the SDK)."""
from __future__ import annotations

import ast
import functools
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Floor of each top-level package; a module may import its own package or any lower floor.
# The diagram's shared floors are ordered too, so that they have no cycle either: hearing < robots
# (the simulated NAO speaks and spots words with hearing's TTS and decoder, as a real NAO's own
# speech engine runs on it), scenarios < bench < cli.
FLOORS = {"ontology": 0, "xmpp_server": 1, "behaviours": 2, "hearing": 2, "robots": 3, "agents": 4, "rapps": 5,
          "scenarios": 6, "bench": 7, "cli": 8}
# drawn side by side in docs/architecture.md: neither imports the other, whatever their floors
APART = {("robots", "behaviours")}
RAPP_ALLOWED = {"rapps.sdk", "ontology"}
EXEMPT = {"hostile_app": "an attacker is not bound to the SDK: that is what its test is about",
          "rtt_probe": "the benchmark's instrument: it logs a plain XMPP client in for the floor"}


@functools.lru_cache(maxsize=None)
def _nodes(path: Path) -> list[ast.AST]:
    return list(ast.walk(ast.parse(path.read_text(), str(path))))


def _imports(path: Path) -> list[tuple[int, str]]:
    """Absolute imports of a file, at any depth (lazy imports inside functions count too)."""
    out = []
    for node in _nodes(path):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module))
    return out


def _rapp_package_dirs() -> list[Path]:
    """Code of every RApp package in the tree (a folder holding manifest.yaml)."""
    return sorted(m.parent for m in [*ROOT.glob("rapps/**/manifest.yaml"), *ROOT.glob("bench/rapps/*/manifest.yaml"),
                                         *ROOT.glob("tests/fixtures/*/manifest.yaml")])


def _project_modules(pkg: str) -> list[Path]:
    packages = _rapp_package_dirs()
    return [f for f in sorted((ROOT / pkg).rglob("*.py"))
            if not any(p in f.parents for p in packages)]


def upward_imports() -> list[str]:
    bad = []
    for pkg, floor in FLOORS.items():
        for f in _project_modules(pkg):
            for line, mod in _imports(f):
                top = mod.split(".")[0]
                if top in FLOORS and top != pkg and FLOORS[top] >= floor:
                    bad.append(f"{f.relative_to(ROOT)}:{line} imports {mod} (floor {FLOORS[top]} >= {floor})")
                elif (pkg, top) in APART or (top, pkg) in APART:
                    bad.append(f"{f.relative_to(ROOT)}:{line} imports {mod} ({pkg} and {top} stand apart)")
    return bad


def rapp_escapes() -> list[str]:
    bad = []
    for d in _rapp_package_dirs():
        if d.name in EXEMPT:
            continue
        own = {p.name for p in d.iterdir() if p.is_dir()}
        for f in sorted(d.rglob("*.py")):
            if "tests" in f.relative_to(d).parts:  # a RApp's own tests: run by `rapp test` and the Store's build
                continue
            for line, mod in _imports(f):
                top = mod.split(".")[0]
                if top in FLOORS and top not in own and not any(mod == a or mod.startswith(a + ".")
                                                                 for a in RAPP_ALLOWED):
                    bad.append(f"{f.relative_to(ROOT)}:{line} imports {mod}")
    return bad


def _module_name(f: Path) -> str:
    parts = f.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported_modules(f: Path, modules: set[str]) -> set[str]:
    """Project modules a file imports, relative imports resolved, at any depth (lazy and TYPE_CHECKING
    imports count: each is a dependency a reader follows)."""
    out: set[str] = set()

    def add(name: str) -> None:
        while name and name not in modules:  # "robots.sound.encode_wav" -> "robots.sound"
            name = name.rpartition(".")[0]
        if name:
            out.add(name)

    for node in _nodes(f):
        if isinstance(node, ast.Import):
            for a in node.names:
                add(a.name)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                here = _module_name(f).split(".")
                package = here if f.name == "__init__.py" else here[:-1]
                base = ".".join(package[:len(package) - node.level + 1] + ([node.module] if node.module else []))
            for a in node.names:
                add(f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base)
    return out


def import_loops() -> list[list[str]]:
    """Sets of modules of one package that import each other in a loop (strongly connected, > 1)."""
    files = {_module_name(f): f for pkg in FLOORS for f in _project_modules(pkg)}
    graph = {m: {t for t in _imported_modules(f, set(files)) if t != m and t.split(".")[0] == m.split(".")[0]}
             for m, f in files.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    loops: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
            if len(component) > 1:
                loops.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return loops


def test_no_upward_import_or_cycle():
    assert upward_imports() == []


def test_rapp_packages_import_only_sdk_and_ontology():
    assert _rapp_package_dirs(), "no RApp package found"
    assert rapp_escapes() == []


def test_every_project_package_has_a_floor():
    pkgs = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"tests"}
    assert pkgs == set(FLOORS), f"give {pkgs ^ set(FLOORS)} a floor in FLOORS and docs/architecture.md"


def test_no_import_loop_inside_a_package():
    assert import_loops() == [], ("modules importing each other in a loop: type the back reference by a "
                                  "Protocol (robots/body.py) or move what both need into a leaf module")


def test_checker_sees_an_import_loop(tmp_path, monkeypatch):
    """The loop checker itself works: two modules of one package importing each other (one of them
    lazily, one relatively) are a loop; a third importing both is not in it."""
    fake = tmp_path / "behaviours"
    fake.mkdir()
    (fake / "__init__.py").write_text("")
    (fake / "a.py").write_text("def f():\n    from behaviours.b import g\n")
    (fake / "b.py").write_text("from .a import f\n")
    (fake / "c.py").write_text("from . import a, b\n")
    me = sys.modules[__name__]
    monkeypatch.setattr(me, "ROOT", tmp_path)
    monkeypatch.setattr(me, "FLOORS", {"behaviours": 2})
    assert import_loops() == [["behaviours.a", "behaviours.b"]]


@pytest.mark.parametrize("src,expect", [("import agents.base\n", 1), ("from ontology import acl\n", 0)])
def test_checker_sees_an_upward_import(tmp_path, monkeypatch, src, expect):
    """The checker itself works: a module of the ontology floor importing agents is reported."""
    fake = tmp_path / "ontology"
    fake.mkdir()
    (fake / "bad.py").write_text(src)
    me = sys.modules[__name__]
    monkeypatch.setattr(me, "ROOT", tmp_path)
    monkeypatch.setattr(me, "FLOORS", {"ontology": 0, "agents": 3})
    assert len(upward_imports()) == expect
