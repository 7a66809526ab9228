"""docs/services.md and docs/robot-api.md are generated from the ontology (rapps/sdk/reference.py) and
stay in step; every example in them runs through the SDK's typed calls against the models; every
error they list (ontology/action_errors.py) is one the implementation can answer, and every code a
service or robot action raises is listed."""
from __future__ import annotations

import ast
import contextlib
import io
import textwrap
from pathlib import Path
from types import SimpleNamespace

import pytest

import rapps.sdk as sdk
from ontology.action_errors import (ROBOT_ERRORS, SERVICE_COMMON, SERVICE_ERRORS, robot_errors, service_errors)
from ontology.errors import ErrorCode
from ontology.platform import ServiceRequest
from ontology.registry import actions, lookup
from ontology.robot_actions import ACTION_FACTS
from rapps.sdk import reference

ROOT = Path(__file__).resolve().parent.parent


def test_the_docs_are_what_the_generator_writes():
    assert reference.SERVICES_MD.read_text() == reference.services_md(), "run: python -m rapps.sdk.reference"
    assert reference.ROBOT_MD.read_text() == reference.robot_md(), "run: python -m rapps.sdk.reference"


def test_every_service_and_action_has_an_entry_with_request_answer_errors_and_example():
    services = {n for n, m in actions("platform").items() if issubclass(m, ServiceRequest)}
    assert set(SERVICE_ERRORS) == services and set(ROBOT_ERRORS) == set(ACTION_FACTS) == set(actions("robot"))
    for doc, names in ((reference.services_md(), services), (reference.robot_md(), ACTION_FACTS)):
        entries = {e.split("`", 1)[0]: e for e in doc.split("\n### `")[1:]}
        assert set(entries) == set(names)
        for name, text in entries.items():
            for part in ("**Request**", "**Answer**", "**Errors**", "**Example**", f".{name}("):
                assert part in text, (name, part)
    door = reference.services_md().split("### `hazard_detection_door_check`")[1].split("\n### ")[0]
    assert "`bad_transform` | `RequestFailed` | `geometry.camera_to_world` is not a 4x4 matrix" in door
    assert "[DoorGeometry](#doorgeometry)" in door and "\n### DoorGeometry\n" in reference.services_md()


def test_the_manifest_keys_the_references_name_are_the_manifests():
    """A RApp author copies the key that grants a service or a robot-API group into manifest.yaml,
    which refuses unknown keys."""
    import re

    from ontology.manifest import Manifest

    for doc in (reference.services_md(), reference.robot_md()):
        named = re.findall(r"manifest(?:'s)? [^.`]*`(\w+)`", doc)
        assert named, doc[:600]
        assert set(named) <= set(Manifest.model_fields), (set(named) - set(Manifest.model_fields))


class Answering:
    """Stands in for the Dynamic Agent's `request` (the transport is tested elsewhere): each request
    must be its action's model, built by the typed call; the answer is the reply model's example."""

    def __init__(self):
        self.sent = []

    async def request(self, to, content, timeout, on_feedback=None):
        assert type(content) is lookup(content.ontology_name, content.action_name)
        self.sent.append(content.action_name)
        reply = content.reply_model
        return reply.model_validate(reference.sample(reply, everything=True))


@pytest.mark.parametrize("name", sorted(reference.examples()))
async def test_every_example_runs_through_the_sdk_against_the_models(name, tmp_path):
    lines = reference.examples()[name]
    source = "async def example(self):\n" + textwrap.indent(
        "\n".join(reference.example_imports(lines) + lines), "    ")
    agent = Answering()
    (tmp_path / "map.png").write_bytes(b"\x89PNG")
    (tmp_path / "map.yaml").write_text("resolution: 0.05\norigin: [0, 0, 0]\n")
    task = SimpleNamespace(robot=sdk.RobotProxy(agent, "core@localhost"),
                           platform=sdk.PlatformProxy(agent, "platform@localhost", "token"),
                           robot_info=SimpleNamespace(robot_type="nao"), outputs=tmp_path)
    scope: dict = {}
    exec(compile(source, f"<example {name}>", "exec"), scope)
    with contextlib.redirect_stdout(io.StringIO()) as out:
        await scope["example"](task)
    assert agent.sent[-1] == name  # the example ends with its own call
    if "print(" in source:
        assert out.getvalue().strip()


# -- the error tables against the code ------------------------------------------------------------
def _functions(folder: str, methods: bool) -> dict:
    """(module, function) -> (ErrorCode members named in it, the functions it calls) for every function
    of a package: calls to its own module's functions and to what it imports relatively are followed;
    with `methods`, a call `x.name(...)` is taken to reach every method `name` of the package (more than
    can happen: an upper bound)."""
    from robots import errors as robot_errors_module
    robot_codes = {n: c.code for n, c in vars(robot_errors_module).items()
                   if isinstance(c, type) and issubclass(c, robot_errors_module.RobotError)}
    funcs, by_method = {}, {}
    fn_types = (ast.FunctionDef, ast.AsyncFunctionDef)
    for path in sorted((ROOT / folder).glob("*.py")):
        mod, tree = path.stem, ast.parse(path.read_text())
        alias = {}
        for node in tree.body:
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                for a in node.names:
                    alias[a.asname or a.name] = (a.name, None) if node.module is None else (node.module, a.name)
        own = {n.name for n in tree.body if isinstance(n, (*fn_types, ast.ClassDef))}

        def body(fn):
            codes, calls = set(), set()
            for n in ast.walk(fn):
                if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id == "ErrorCode":
                    codes.add(ErrorCode[n.attr])
                if isinstance(n, ast.Raise) and isinstance(n.exc, ast.Call) and isinstance(n.exc.func, ast.Name) \
                        and n.exc.func.id in robot_codes:
                    codes.add(robot_codes[n.exc.func.id])
                if isinstance(n, ast.Call):
                    f = n.func
                    if isinstance(f, ast.Name) and f.id in own:
                        calls.add((mod, f.id))
                    elif isinstance(f, ast.Name) and f.id in alias and alias[f.id][1]:
                        calls.add(alias[f.id])
                    elif isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id in alias \
                            and alias[f.value.id][1] is None:
                        calls.add((alias[f.value.id][0], f.attr))
                    elif isinstance(f, ast.Attribute) and methods:
                        calls.add(("*", f.attr))
            return codes, calls

        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                for item in node.body:
                    if isinstance(item, fn_types):
                        key = (mod, node.name if item.name == "__init__" else f"{node.name}.{item.name}")
                        funcs[key] = body(item)
                        by_method.setdefault(item.name, []).append(key)
            elif isinstance(node, fn_types):
                funcs.setdefault((mod, node.name), body(node))
    for codes, calls in funcs.values():
        for c in [c for c in calls if c[0] == "*"]:
            calls.discard(c)
            calls.update(by_method.get(c[1], []))
    return funcs


def _reach(funcs, start) -> set:
    seen, todo, codes = set(), [start], set()
    while todo:
        key = todo.pop()
        if key not in seen and key in funcs:
            seen.add(key)
            codes |= funcs[key][0]
            todo += funcs[key][1]
    return codes


def test_each_services_errors_are_the_codes_its_implementation_raises():
    from agents.services.registry import SERVICES
    exact, upper = _functions("agents/services", False), _functions("agents/services", True)
    pool = {c for (m, _), (codes, _) in upper.items() if m == "pool" for c in codes}
    common = {e.code for e in SERVICE_COMMON}
    for name, spec in SERVICES.items():
        fn = spec.run
        start = (fn.__module__.rsplit(".", 1)[1], fn.__name__)
        declared = {e.code for e in service_errors(name)}
        assert _reach(exact, start) <= declared, f"{name} raises codes ontology/action_errors.py does not list"
        possible = _reach(upper, start) | (pool if spec.pooled else set()) | common
        assert set(SERVICE_ERRORS[name]) <= possible, f"{name}: listed codes its implementation never raises"


def test_each_robot_actions_errors_are_the_codes_the_robot_raises():
    exact, upper = _functions("robots", False), _functions("robots", True)
    for name in ACTION_FACTS:
        if ACTION_FACTS[name].core:
            continue  # served by the Core (agents/core_commands.py `_lock`, `_free`; agents/core_localizer.py)
        start = ("api", f"RobotAPI.{name}")
        assert start in exact, name
        declared = {e.code for e in robot_errors(name)}
        assert exact[start][0] <= declared, f"{name} raises codes ontology/action_errors.py does not list"
        assert set(ROBOT_ERRORS[name]) <= _reach(upper, start), f"{name}: listed codes the robot never raises"


def test_error_facts_follow_the_action_facts():
    codes = lambda n: {e.code for e in robot_errors(n)}  # noqa: E731
    assert ErrorCode.ESTOP in codes("move_to") and ErrorCode.ESTOP not in codes("move_along_path")
    assert ErrorCode.BLOCKED in codes("move_along_path") and ErrorCode.BLOCKED not in codes("look_at_point")
    assert ErrorCode.LOCKED in codes("capture_image") and ErrorCode.LOCKED not in codes("get_global_pose")
    assert ErrorCode.PERMISSION not in codes("lock_resource")  # needs no manifest group
