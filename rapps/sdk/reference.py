"""Writes docs/services.md and docs/robot-api.md from the ontology: every Platform service a RApp may
be granted and every robot action, each with its request (fields, types, defaults, constraints and
meaning, read from the models and their source comments), its answer, its errors
(ontology/action_errors.py) and an example call with an example answer. tests/test_reference.py
fails when the docs are not what this writes, and runs every example through the SDK's typed calls
against the models (`examples()`):

    python -m rapps.sdk.reference
"""
from __future__ import annotations

import inspect
import json
import re
import sys
import types
import typing
from collections.abc import Callable, Iterable, Sequence, Set
from pathlib import Path
from typing import Any, cast

from annotated_types import Ge, Gt, Le, Lt, MaxLen, MinLen
from pydantic import BaseModel, TypeAdapter, ValidationError
from pydantic.fields import FieldInfo

import ontology.robot  # noqa: F401 - registers the robot actions
import ontology.services  # noqa: F401 - registers the Platform services
from ontology.action_errors import EXCEPTION, ROBOT_ERRORS, SERVICE_ERRORS, ErrorFact, robot_errors, service_errors
from ontology.platform import ServiceRequest
from ontology.registry import Action, Content, actions
from ontology.robot_actions import ACTION_FACTS

from .generate import HIDDEN, _Types

DOCS = Path(__file__).resolve().parents[2] / "docs"
SERVICES_MD, ROBOT_MD = DOCS / "services.md", DOCS / "robot-api.md"


# -- what a field means ---------------------------------------------------------------------------
def _comments(cls: type) -> dict[str, str]:
    """field -> its source comment (the line's own, else the comment lines just above it)."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not (isinstance(klass, type) and issubclass(klass, BaseModel)) or klass.__module__ == "pydantic.main":
            continue
        try:
            lines = inspect.getsource(klass).splitlines()
        except (OSError, TypeError):
            continue
        above: list[str] = []
        for line in lines:
            s = line.strip()
            if s.startswith("#"):
                above.append(s.lstrip("#").strip())
                continue
            m = re.match(r"(\w+):[^#]*?(?:#\s*(.*))?$", s)
            if m and m.group(1) in klass.model_fields:
                own = (m.group(2) or "").replace("noqa", "").strip()
                text = " ".join(above + ([own] if own else []))
                if text:
                    out[m.group(1)] = text
            above = []
    return out


def _constraints(info: FieldInfo) -> str:
    parts: list[str] = []
    for m in info.metadata:
        for kind, sym in ((Gt, ">"), (Ge, ">="), (Lt, "<"), (Le, "<=")):
            if isinstance(m, kind):
                parts.append(f"{sym} {getattr(m, kind.__name__.lower())}")
        if isinstance(m, MinLen):
            parts.append(f"length >= {m.min_length}")
        if isinstance(m, MaxLen):
            parts.append(f"length <= {m.max_length}")
        pattern = getattr(m, "pattern", None)
        if isinstance(pattern, str):
            parts.append(f"matches `{pattern}`")
    return ", ".join(parts)


def _default(info: FieldInfo) -> str:
    if info.is_required():
        return "required"
    # the models' default factories take no argument (none reads the fields validated before it)
    factory = cast("Callable[[], Any] | None", info.default_factory)
    value = factory() if factory is not None else info.default
    if isinstance(value, BaseModel):
        value = value.model_dump()
    return f"`{json.dumps(value)}`" if value is not None else "`null`"


def _nested(tp: Any) -> list[type[BaseModel]]:
    """The Content models a type refers to (list[Pose2D] -> [Pose2D])."""
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return [tp]
    return [m for a in typing.get_args(tp) for m in _nested(a)]


def _anchor(name: str) -> str:
    return name.lower().replace("_", "-")


def _type_cell(tp: Any, t: _Types) -> str:
    text = t.name(tp)
    for m in _nested(tp):
        text = re.sub(rf"\b{m.__name__}\b", f"[{m.__name__}](#{_anchor(m.__name__)})", text)
    return text.replace("|", "\\|")


def field_table(model: type[BaseModel], t: _Types, hidden: Set[str] = frozenset()) -> list[str]:
    fields = [(n, i) for n, i in model.model_fields.items() if n not in hidden]
    if not fields:
        return ["(no fields)"]
    notes = _comments(model)
    rows = ["| field | type | default | meaning |", "|---|---|---|---|"]
    for name, info in fields:
        meaning = "; ".join(x for x in (info.description or notes.get(name, ""), _constraints(info)) if x)
        rows.append(f"| `{name}` | {_type_cell(info.annotation, t)} | {_default(info)} | "
                    f"{meaning.replace('|', '/')} |")
    return rows


# -- example values -------------------------------------------------------------------------------
IDENTITY = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
K = [[277.1, 0.0, 159.5], [0.0, 277.1, 119.5], [0.0, 0.0, 1.0]]
NAMED: dict[str, Any] = {  # example values by field name, where a type alone says too little
    "matrix": IDENTITY, "camera_to_world": IDENTITY, "camera_to_robot": IDENTITY, "pose_in_camera": IDENTITY,
    "K": K, "P": [[277.1, 0.0, 159.5, 0.0], [0.0, 277.1, 119.5, 0.0], [0.0, 0.0, 1.0, 0.0]],
    "map_id": "home_map", "home_id": "home", "robot_type": "nao", "camera": "camera", "chain": "camera",
    "resource": "base", "posture": "Stand", "text": "Hello", "city": "Athens", "email": "owner@example.org",
    "user": "owner", "rapp": "hazard-detection", "language": "en", "name": "default", "ip": "192.0.2.1",
    "hinge": [3.5, 1.0], "closed_yaw_deg": 90.0, "look_at": [3.5, 1.35, 0.0], "rect": [0.05, 0.05, 3.45, 3.95],
    "corners": [[100.0, 80.0], [140.0, 80.0], [140.0, 120.0], [100.0, 120.0]], "joints": ["HeadYaw"],
    "angles": [0.3], "words": ["yes", "no"], "test_type": "ArithmeticCts", "recipients": ["owner@example.org"],
    "query": "robots", "class_name": "Lamp", "parent": "Furniture", "child": "Lamp", "data_b64": "UklGRg==",
}
_SIMPLE: dict[type, list[Any]] = {float: [1.0, 0.5, 2.0, 50.0], int: [1, 2, 50, 160, 16000], bool: [False, True], str: ["example"]}


def _fits(tp: Any, metadata: Sequence[Any], value: Any) -> bool:
    try:
        TypeAdapter(typing.Annotated[tp, *metadata] if metadata else tp).validate_python(value)
        return True
    except (ValidationError, TypeError):
        return False


def _candidates(tp: Any, name: str) -> list[Any]:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Annotated:
        return _candidates(args[0], name)
    if origin is typing.Literal:
        return list(args)
    if origin in (typing.Union, types.UnionType):
        return [c for a in args if a is not type(None) for c in _candidates(a, name)] + [None]
    if origin in (list, tuple, set):
        item = sample_value(args[0] if args else Any, name) if args and args[0] is not Ellipsis else 1.0
        if origin is tuple and args and args[-1] is not Ellipsis:
            return [tuple(sample_value(a, name) for a in args)]
        return [[item] * n for n in (1, 2, 3, 4, 0)]
    if origin is dict:
        return [{}]
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return [sample(tp)]
    if tp is Any:
        return [{}]
    if isinstance(tp, type) and issubclass(tp, str) and tp is not str:  # a StrEnum
        return [next(iter(cast("Iterable[Any]", tp)))]
    return list(_SIMPLE.get(tp, ["example"]))


def sample_value(tp: Any, name: str = "", metadata: Sequence[Any] = ()) -> Any:
    """A value of type `tp` that passes the field's constraints (by name where NAMED has one)."""
    for value in ([NAMED[name]] if name in NAMED else []) + _candidates(tp, name):
        if _fits(tp, metadata, value):
            return value.model_dump() if isinstance(value, BaseModel) else value
    raise ValueError(f"no example value of {tp} for {name!r}")


def sample(model: type[BaseModel], everything: bool = False) -> dict[str, Any]:
    """Example content: every required field (with `everything`, every field) with a value that fits;
    a request's token is left to the SDK."""
    out: dict[str, Any] = {}
    for name, info in model.model_fields.items():
        if (name in HIDDEN and issubclass(model, ServiceRequest)) or not (everything or info.is_required()):
            continue
        out[name] = sample_value(info.annotation, name, info.metadata)
    model.model_validate(out)  # validators across fields
    return out


# -- the examples ---------------------------------------------------------------------------------
IMAGE = 'image = await self.robot.capture_image(resolution="640x480")'
AUDIO = "audio = await self.robot.capture_audio(seconds=2.0)"
FROM = {"image_b64": (IMAGE, "image.data_b64"), "audio_b64": (AUDIO, "audio.data_b64"),
        "png_b64": ('png = (self.outputs / "map.png").read_bytes()', "base64.b64encode(png).decode()"),
        "yaml_text": ('yaml_text = (self.outputs / "map.yaml").read_text()', "yaml_text")}
# hand-written calls where the required fields alone would not show how the call is meant
CURATED: dict[str, tuple[list[str], str]] = {
    "hazard_detection_door_check": (
        ['home = await self.platform.home_get_info(home_id="home")', 'door = home.doors[0]',
         IMAGE, 'info = await self.robot.get_camera_info(resolution="640x480")',
         'tf = await self.robot.get_transform(chain="camera", space="global")',
         "geometry = DoorGeometry(camera=CameraIntrinsics(fx=info.K[0][0], fy=info.K[1][1], cx=info.K[0][2], "
         "cy=info.K[1][2]),", "                        camera_to_world=tf.matrix, hinge=door.door.hinge, "
         "closed_yaw_deg=door.door.closed_yaw_deg, width_m=door.door.width_m)"],
        'image_b64=image.data_b64, method="geometry", geometry=geometry'),
    "hazard_detection_light_check": (
        ["await self.robot.set_camera_params(exposure=0.3)", IMAGE], "image_b64=image.data_b64, on_threshold=30"),
    "path_planning_plan_path_2d": (
        ['home = await self.platform.home_get_info(home_id="home")',
         "start = await self.robot.get_global_pose()"],
        "map_id=home.map_id, robot_type=self.robot_info.robot_type, start=start, goal=home.hazards[0].stand"),
    "qr_detection": (
        [IMAGE, 'info = await self.robot.get_camera_info(resolution="640x480")'],
        "image_b64=image.data_b64, camera=CameraIntrinsics(fx=info.K[0][0], fy=info.K[1][1], cx=info.K[0][2], "
        "cy=info.K[1][2]), code_size_m=0.25"),
    "move_along_path": (
        ['plan = await self.platform.path_planning_plan_path_2d(map_id="home_map", robot_type="nao",',
         "    start={\"x\": 1.0, \"y\": 2.0, \"theta\": 0.0}, goal={\"x\": 5.0, \"y\": 2.0, \"theta\": 0.0})"],
        "poses=plan.path, _timeout=600.0"),
    "look_at_point": ([], "x=3.5, y=1.0, z=0.0"),
    "path_planning_clear_obstacles": ([], 'map_id="home_map", x=3.5, y=1.2, radius_m=0.5'),
    "move_to": ([], "x=0.5, theta=0.3"),
    "say": ([], 'text="Hello, I am checking the doors."'),
    "set_camera_params": ([], "exposure=0.3, auto_exposure=False"),
    "word_spotting": ([], 'words=["yes", "no"], timeout=10.0'),
    "play_audio": (['speech = await self.platform.text_to_speech(text="Hello")'], "data_b64=speech.audio_b64"),
    "speech_recognition": ([AUDIO], 'audio_b64=audio.data_b64, sentences=["check the doors", "stop"]'),
    "lock_resource": ([], 'resource="camera", timeout_s=5.0'),
}
IMPORTS = {"DoorGeometry": "ontology.services.hazard", "CameraIntrinsics": "ontology.services.common",
           "base64": None}


def _py(value: Any) -> str:
    return json.dumps(value).replace("true", "True").replace("false", "False").replace("null", "None")


def example(name: str, model: type[Action]) -> list[str]:
    """The example's lines, as the body of an `async def` of a Task (self.robot, self.platform)."""
    proxy = "self.platform" if issubclass(model, ServiceRequest) else "self.robot"
    if name in CURATED:
        setup, kwargs = CURATED[name]
        setup = list(setup)
    else:
        setup, args = [], []
        for field, value in sample(model).items():
            if field in FROM:
                setup.append(FROM[field][0])
                args.append(f"{field}={FROM[field][1]}")
            else:
                args.append(f"{field}={_py(value)}")
        kwargs = ", ".join(args)
    reply = model.reply_model
    shown = [f for f in (reply.model_fields if reply is not None else []) if f != "ok"][:2]
    call = f"await {proxy}.{name}({kwargs})"
    if not shown:
        return setup + [call]
    return setup + [f"reply = {call}", f"print({', '.join(f'reply.{f}' for f in shown)})"]


def example_imports(lines: list[str]) -> list[str]:
    text = "\n".join(lines)
    out = []
    for name, module in IMPORTS.items():
        if re.search(rf"\b{name}\b", text):
            out.append(f"import {name}" if module is None else f"from {module} import {name}")
    return out


def examples() -> dict[str, list[str]]:
    """Every entry's example (what the docs show), for tests/test_reference.py to run."""
    out = {}
    for name, model in sorted(actions("platform").items()):
        if issubclass(model, ServiceRequest):
            out[name] = example(name, model)
    for name, model in sorted(actions("robot").items()):
        out[name] = example(name, model)
    return out


# -- the documents --------------------------------------------------------------------------------
def _errors_table(errors: list[ErrorFact]) -> list[str]:
    rows = ["| code | raised as | when |", "|---|---|---|"]
    rows += [f"| `{e.code}` | `{EXCEPTION[e.answer]}` | {e.when} |" for e in errors]
    return rows


def _entry(name: str, model: type[Action], t: _Types, errors: list[ErrorFact], facts_line: str) -> list[str]:
    doc = inspect.cleandoc(model.__doc__ or "") if "Base of" not in (model.__doc__ or "") else ""
    reply = _reply(model)
    lines = [f"### `{name}`", ""]
    if doc:
        lines += [doc, ""]
    lines += [facts_line, "", f"**Request** `{model.__name__}`:", "", *field_table(model, t, HIDDEN), ""]
    lines += [f"**Answer** [`{reply.__name__}`](#{_anchor(reply.__name__)})"
              + (": `{\"ok\": true}`" if reply.__name__ == "Done" else ""), ""]
    own = [e for e in errors if e.code in _own_codes(name)]
    lines += ["**Errors** (besides the common ones above): " + (", ".join(f"`{e.code}`" for e in own) if own
                                                                 else "none of its own") + ".", ""]
    if own:
        lines += _errors_table(own) + [""]
    body = example(name, model)
    lines += ["**Example**:", "", "```python", *example_imports(body), *body, "```", ""]
    if reply is not None and reply.__name__ != "Done":
        lines += ["Example answer:", "", "```json", json.dumps(sample(reply, everything=True)), "```", ""]
    return lines


def _reply(model: type[Action]) -> type[Content]:
    """The action's answer model (`ontology.registry.action` gives every action one)."""
    if model.reply_model is None:  # what reading the answer's name would have raised
        raise AttributeError(f"{model.__name__} has no reply model")
    return model.reply_model


def _own_codes(name: str) -> set[str]:
    return set(SERVICE_ERRORS.get(name) or ROBOT_ERRORS.get(name) or {})


def _models_section(t: _Types, requests: list[type[Action]]) -> list[str]:
    """The answers and every model a request or answer holds."""
    seen: dict[str, type[BaseModel]] = {}
    todo = [_reply(m) for m in requests] + [n for m in requests for i in m.model_fields.values()
                                                 for n in _nested(i.annotation)]
    while todo:
        m = todo.pop()
        if m.__name__ in seen:
            continue
        seen[m.__name__] = m
        for info in m.model_fields.values():
            todo += _nested(info.annotation)
    lines = ["## Models", "", "The answers and the models the requests and answers hold, by name.", ""]
    for mname in sorted(seen):
        m = seen[mname]
        doc = inspect.cleandoc(m.__doc__ or "")
        lines += [f"### {mname}", "", f"`{m.__module__}.{mname}`" + (f": {doc}" if doc else ""), "",
                  *field_table(m, t), ""]
    return lines


def _summary(model: type[Action]) -> str:
    """The first paragraph of a request's docstring, else of its answer's."""
    for m in (model, model.reply_model):
        doc = m.__doc__ or "" if m is not None else ""
        if doc and "Base of" not in doc and "Generic reply" not in doc:
            return " ".join(inspect.cleandoc(doc).split("\n\n")[0].split())
    return ""


HEAD = "<!-- GENERATED by `python -m rapps.sdk.reference` from the ontology: do not edit. -->"


def services_md() -> str:
    t = _Types()
    services = sorted((n, m) for n, m in actions("platform").items() if issubclass(m, ServiceRequest))
    groups: dict[str, list[tuple[str, type[ServiceRequest]]]] = {}
    for n, m in services:
        groups.setdefault(m.group, []).append((n, m))
    lines = [HEAD, "# Platform services: the reference", "",
             "Every service a RApp may call on the Platform, generated from the ontology (ontology/services/, "
             "ontology/platform.py) with its errors (ontology/action_errors.py). A RApp calls one as "
             "`await self.platform.<service>(**fields)` (rapps/sdk/calls.py: typed, the token is added for "
             "you), after declaring it in its manifest's `services`. Fields are keyword "
             "arguments; a nested model may be given as the model or as a dict. Units: metres, radians "
             "(degrees where a name says `_deg`), seconds. The examples are the body of an `async def` "
             "of a Task; tests/test_reference.py runs each one through the SDK against the models.", "",
             "## Errors every service may answer", "",
             "A refusal means nothing was done; a failure that it was tried. The exceptions are "
             "rapps.sdk's (all `RequestError`, with `.code` and `.reason`).", "",
             *_errors_table([e for e in service_errors("home_get_info") if e.code not in _own_codes("home_get_info")]),
             "", "## Index", "", "| service | group | what |", "|---|---|---|"]
    for n, m in services:
        lines.append(f"| [`{n}`](#{_anchor(n)}) | {m.group} | {_summary(m).replace('|', '/')} |")
    lines.append("")
    for group in sorted(groups):
        lines += [f"## {group}", ""]
        for n, m in groups[group]:
            facts = f"Group `{m.group}`; " + ("a read: sent again after a timeout." if m.idempotent
                                               else "not repeated after a timeout.")
            lines += _entry(n, m, t, service_errors(n), facts)
    lines += _models_section(t, [m for _, m in services])
    return "\n".join(lines).rstrip() + "\n"


def robot_md() -> str:
    t = _Types()
    robot = actions("robot")
    lines = [HEAD, "# Robot API: the reference", "",
             "Every action the Core serves to the RApp it supervises, generated from the ontology "
             "(ontology/robot.py, ontology/robot_actions.py) with its errors (ontology/action_errors.py). "
             "A RApp calls one as `await self.robot.<action>(**fields)` (rapps/sdk/calls.py), after "
             "declaring its group in its manifest's `robot_api` (`resources` needs none). Units: metres, "
             "radians, seconds of simulation time; poses in the global (map) frame unless stated: "
             "`get_global_pose` is the robot's own estimate (odometry, corrected by `set_global_pose`), "
             "not the truth. The camera's optical frame is x right, y down, z forward. The examples are "
             "the body of an `async def` of a Task; tests/test_reference.py runs each one through the "
             "SDK against the models.", "",
             "## Errors every action may answer", "",
             *_errors_table([e for e in robot_errors("get_global_pose")]), "",
             "An action that holds a device (column `device`) may also be refused `locked`; a motion "
             "fails `interrupted` when a newer one pre-empts it, a base motion `blocked`, a relative one "
             "(`move_to`, `move_vel`) `estop` (each listed with the action).", "",
             "## Index", "", "| action | group | device | motion | read | what |", "|---|---|---|---|---|---|"]
    for n in ACTION_FACTS:
        m, f = robot[n], ACTION_FACTS[n]
        first = _summary(m)
        lines.append(f"| [`{n}`](#{_anchor(n)}) | {f.group} | {f.device or '–'} | {'yes' if f.motion else 'no'} | "
                     f"{'yes' if f.idempotent else 'no'} | {first.replace('|', '/')} |")
    lines.append("")
    groups: dict[str, list[str]] = {}
    for n, f in ACTION_FACTS.items():
        groups.setdefault(f.group, []).append(n)
    common = {e.code for e in robot_errors("get_global_pose")}
    for group, names in groups.items():
        lines += [f"## {group}", ""]
        for n in names:
            f = ACTION_FACTS[n]
            facts = (f"Group `{f.group}`; device `{f.device}`" if f.device else f"Group `{f.group}`; no device") \
                + ("; a motion (held while the emergency stop is latched)" if f.motion else "") \
                + ("; a read: sent again after a timeout." if f.idempotent else ".")
            entry = _entry(n, robot[n], t, robot_errors(n), facts)
            extra = [e for e in robot_errors(n) if e.code not in common and e.code not in _own_codes(n)]
            if extra:
                i = entry.index("**Example**:")
                entry[i:i] = [f"As {'a motion' if f.motion else 'the holder of a device'}:", "", *_errors_table(extra), ""]
            lines += entry
    lines += _models_section(t, [robot[n] for n in ACTION_FACTS])
    return "\n".join(lines).rstrip() + "\n"


def main() -> int:
    SERVICES_MD.write_text(services_md())
    ROBOT_MD.write_text(robot_md())
    print(SERVICES_MD)
    print(ROBOT_MD)
    return 0


if __name__ == "__main__":
    sys.exit(main())
