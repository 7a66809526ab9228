"""The layer diagram of docs/architecture.md, enforced: every project module imports only from its
own floor or those below, the floors form no cycle, and a RApp package's code imports only the SDK
and the ontology (so it runs from its package alone on any Platform that offers the SDK)."""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Floor of each top-level package; a module may import its own package or any lower floor.
# The top floor is ordered too (scenarios < bench < cli) so that it has no cycle either.
FLOORS = {"ontology": 0, "xmpp_server": 1, "behaviours": 2, "robots": 2, "agents": 3, "rapps": 4,
          "scenarios": 5, "bench": 6, "cli": 7}
RAPP_ALLOWED = {"rapps.sdk", "ontology"}
EXEMPT = {"hostile_app": "an attacker is not bound to the SDK: that is what its test is about",
          "rtt_probe": "the benchmark's instrument: it logs a plain XMPP client in for the floor"}


def _imports(path: Path) -> list[tuple[int, str]]:
    """Absolute imports of a file, at any depth (lazy imports inside functions count too)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
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
    return bad


def rapp_escapes() -> list[str]:
    bad = []
    for d in _rapp_package_dirs():
        if d.name in EXEMPT:
            continue
        own = {p.name for p in d.iterdir() if p.is_dir()}
        for f in sorted(d.rglob("*.py")):
            if "tests" in f.relative_to(d).parts:  # a RApp's own tests run here, are not shipped
                continue
            for line, mod in _imports(f):
                top = mod.split(".")[0]
                if top in FLOORS and top not in own and not any(mod == a or mod.startswith(a + ".")
                                                                 for a in RAPP_ALLOWED):
                    bad.append(f"{f.relative_to(ROOT)}:{line} imports {mod}")
    return bad


def test_no_upward_import_or_cycle():
    assert upward_imports() == []


def test_rapp_packages_import_only_sdk_and_ontology():
    assert _rapp_package_dirs(), "no RApp package found"
    assert rapp_escapes() == []


def test_every_project_package_has_a_floor():
    pkgs = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"tests"}
    assert pkgs == set(FLOORS), f"give {pkgs ^ set(FLOORS)} a floor in FLOORS and docs/architecture.md"


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
