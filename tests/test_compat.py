"""xmpp_server/compat.py: the patches of SPADE, slixmpp and pyjabber internals are installed by one
call that checks the pinned versions first, and nothing outside it overrides or patches them."""
from __future__ import annotations

import ast
import importlib
import inspect

import pytest

from xmpp_server import compat


def test_installed_versions_match_the_pins():
    assert compat.check_pins() == compat.PINS


def test_another_version_is_refused_with_a_clear_message(monkeypatch):
    monkeypatch.setitem(compat.PINS, "spade", "9.9.9")
    with pytest.raises(compat.PinMismatch, match=r"spade 4\.1\.4 is installed but 9\.9\.9 is pinned.*pip install"):
        compat.check_pins("spade")
    monkeypatch.setitem(compat.PINS, "no-such-dist", "1.0")
    with pytest.raises(compat.PinMismatch, match="no-such-dist is not installed"):
        compat.check_pins("no-such-dist")


def test_agent_patches_are_installed_once_and_checked(monkeypatch):
    import spade.agent
    from spade.behaviour import CyclicBehaviour

    compat.install_agent_patches()
    assert CyclicBehaviour._step is compat._cancellable_step
    assert spade.agent.XMPPClient is compat.rapp_xmpp_client_class()
    compat.install_agent_patches()  # idempotent
    assert spade.agent.XMPPClient is compat.rapp_xmpp_client_class()
    monkeypatch.setattr(compat, "_installed", set())
    monkeypatch.setitem(compat.PINS, "pyjabber", "0.0.1")
    with pytest.raises(compat.PinMismatch):  # a mismatch stops before anything is patched again
        compat.install_agent_patches()


# -- the door: no override of, or patch into, SPADE, slixmpp or pyjabber outside compat.py --------
# (ruff's SLF001 catches reads of their private members; these catch what a linter does not see)
THIRD_PARTY = ("spade", "slixmpp", "pyjabber")
DOOR = "xmpp_server/compat.py"
_INTERNALS_OF = ["spade.agent", "spade.behaviour", "spade.message", "spade.template", "spade.presence",
                 "slixmpp.basexmpp", "slixmpp.clientxmpp", "slixmpp.xmlstream.xmlstream"]


def _private_names() -> set[str]:
    """Private methods and attributes (`self._x`) of the pinned SPADE and slixmpp classes ours derive from."""
    names: set[str] = set()
    for module in _INTERNALS_OF:
        for node in ast.walk(ast.parse(inspect.getsource(importlib.import_module(module)))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                names.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "self":
                names.add(node.attr)
    return {n for n in names if n.startswith("_") and not n.startswith("__")}


def _project_trees():
    from .test_layers import FLOORS, ROOT

    for pkg in FLOORS:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            yield str(path.relative_to(ROOT)), ast.parse(path.read_text(), str(path))


def reach_ins(trees=None) -> list[str]:
    """Where a project class derived from a SPADE/slixmpp/pyjabber class overrides or sets one of their
    private members, or a module assigns into something imported from them, outside compat.py."""
    trees = list(trees if trees is not None else _project_trees())
    private = _private_names()
    third_names: dict[str, set[str]] = {}  # file -> names bound to a third-party module or its members
    bases: dict[tuple[str, str], list[str]] = {}
    for where, tree in trees:
        names = third_names.setdefault(where, set())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in THIRD_PARTY:
                names.update(a.asname or a.name for a in node.names)
            elif isinstance(node, ast.Import):
                names.update((a.asname or a.name).split(".")[0] for a in node.names
                             if a.name.split(".")[0] in THIRD_PARTY)
            elif isinstance(node, ast.ClassDef):
                bases[(where, node.name)] = [ast.unparse(b) for b in node.bases]
    derived: set[str] = set()  # class names (a name-level approximation across modules)
    changed = True
    while changed:
        changed = False
        for (where, name), bs in bases.items():
            if name not in derived and any(b.split(".")[0] in third_names[where] or b.split(".")[-1] in derived
                                           for b in bs):
                derived.add(name)
                changed = True
    found = []
    for where, tree in trees:
        if where == DOOR:
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef) and node.name in derived:
                for item in ast.walk(node):
                    name = None
                    if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) and item in node.body:
                        name = item.name
                    elif (isinstance(item, ast.Attribute) and isinstance(item.ctx, ast.Store)
                          and isinstance(item.value, ast.Name) and item.value.id == "self"):
                        name = item.attr
                    if name in private:
                        found.append(f"{where}:{item.lineno} {node.name} sets {name}")
            elif isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                for t in targets:
                    base = t
                    while isinstance(base, ast.Attribute):
                        base = base.value
                    if isinstance(t, ast.Attribute) and isinstance(base, ast.Name) and base.id in third_names[where]:
                        found.append(f"{where}:{node.lineno} patches {ast.unparse(t)}")
    return found


def test_no_override_or_patch_of_spade_slixmpp_or_pyjabber_outside_the_door():
    assert reach_ins() == []


def test_the_door_check_sees_an_override_and_a_patch():
    """The checker itself works: an agent class overriding SPADE's _message_received, a module
    patching a slixmpp class, and one setting a behaviour's private _exit_code are each reported."""
    src = ("from spade.agent import Agent\nfrom spade.behaviour import CyclicBehaviour\n"
           "from slixmpp import ClientXMPP\n"
           "class Mine(Agent):\n    def _message_received(self, node):\n        pass\n"
           "class Sub(Mine):\n    pass\n"
           "class B(CyclicBehaviour):\n    async def run(self):\n        self._exit_code = 1\n"
           "ClientXMPP.connect = None\n"
           "class Plain:\n    def _message_received(self):\n        pass\n")
    found = reach_ins([("agents/fake.py", ast.parse(src))])
    assert [f.split(" ", 1)[1] for f in found] == ["Mine sets _message_received", "B sets _exit_code",
                                                   "patches ClientXMPP.connect"], found


def test_an_agents_process_imports_spade_without_its_xmpp_server(tmp_path):
    """agents/runtime.py stands in for pyjabber before SPADE's import: the server's sqlalchemy, alembic
    and x509 are not loaded (0.4 s and ~35 MB per RApp process), SPADE's agents work, and the stand-in
    refuses to run a server with a clear error. A process with pyjabber loaded is left as it is."""
    import subprocess
    import sys

    probe = ("import sys\nfrom xmpp_server.compat import spade_without_its_server\n"
             "spade_without_its_server()\nimport agents.dynamic_agent, agents.cloud_agent, spade.container\n"
             "print(sorted({m.split('.')[0] for m in sys.modules} & {'sqlalchemy', 'alembic', 'cryptography'}))\n"
             "try:\n    spade.container.Server(None)\nexcept RuntimeError as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True).stdout
    assert out.splitlines()[0] == "[]", out
    assert "runs agents only" in out.splitlines()[1]
    server_first = ("import pyjabber.server\nfrom xmpp_server.compat import spade_without_its_server\n"
                    "spade_without_its_server()\nimport spade.container, sys\n"
                    "print(spade.container.Server is sys.modules['pyjabber.server'].Server, 'alembic' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", server_first], capture_output=True, text=True, timeout=120,
                         check=True).stdout
    assert out.split() == ["True", "True"]
    assert "spade_without_its_server()" in inspect.getsource(importlib.import_module("agents.runtime").main)


def test_the_rapp_program_loads_no_server_unless_it_is_one():
    """`rapp` started as a program stands in for pyjabber (its servers are child processes), except
    `rapp server`, which runs pyjabber itself; a caller's main([...]) changes nothing in its process."""
    import subprocess
    import sys

    probe = ("import sys\nsys.argv = ['rapp', *sys.argv[1:]]\nfrom cli import main\n"
             "try:\n    main.main()\nexcept SystemExit:\n    pass\n"
             "stand_in = 'stand-in' in (getattr(sys.modules.get('pyjabber'), '__doc__', None) or '')\n"
             "print('STOOD-IN' if stand_in else 'AS-SHIPPED')\n")
    said = {}
    for args in (["trace", "--help"], ["--debug", "server", "--help"]):
        out = subprocess.run([sys.executable, "-c", probe, *args], capture_output=True, text=True, timeout=120,
                             stdin=subprocess.DEVNULL).stdout
        said[args[-2]] = out.split()[-1]
    assert said == {"trace": "STOOD-IN", "server": "AS-SHIPPED"}, said


def test_other_versions_than_the_pins_get_no_stand_in():
    """An installation off its pins keeps pyjabber as it is, so `rapp doctor` and the agent patches
    report the mismatch instead of a traceback from the stand-in's own check."""
    import subprocess
    import sys

    probe = ("import sys\nfrom xmpp_server import compat\ncompat.PINS['pyjabber'] = '0.0.1'\n"
             "compat.spade_without_its_server()\nprint('pyjabber' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.split() == ["False"], out.stderr
