"""Registry of actions: every action's content is a pydantic model registered under its name.

    @action("say", ontology="robot", reply=Done)
    class Say(Action):
        text: str

`decode_request` validates an incoming body against the registered model and raises
`ContentError` naming the problem (unknown action, malformed JSON, invalid fields).
"""
from __future__ import annotations

import json
from typing import Any, Callable, ClassVar, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError


class Content(BaseModel):
    """Base of every message content. Unknown fields are refused so typos surface as errors."""

    model_config = ConfigDict(extra="forbid")


class Action(Content):
    """Base of request contents. Subclasses are registered with @action."""

    action_name: ClassVar[str] = ""
    ontology_name: ClassVar[str] = ""
    reply_model: ClassVar[type[Content] | None] = None
    # robot-API group or platform service name the action belongs to (for permissions)
    group: ClassVar[str] = ""
    # a read without side effects: safe to send again after a timeout (e.g. a server restart);
    # declared where the action is registered (robot actions: ontology/robot_actions.py), never guessed
    idempotent: ClassVar[bool] = False


class Done(Content):
    """Generic reply of an action that returns nothing but success."""

    ok: bool = True


class Progress(Content):
    """Feedback of a long action (acl.FEEDBACK): how far it is (0..1 or None) and what it does."""

    fraction: float | None = None
    text: str = ""
    data: dict[str, Any] = {}


class ContentError(ValueError):
    """Raised when a body cannot be turned into the registered model; the text names the problem."""


_actions: dict[tuple[str, str], type[Action]] = {}
A = TypeVar("A", bound=type[Action])  # an Action class: the decorators return it as it is


def action(name: str, *, ontology: str, reply: type[Content] = Done, group: str = "",
           idempotent: bool = False) -> Callable[[A], A]:
    """Class decorator registering an Action model under (ontology, name). `idempotent=True` marks a
    read without side effects (the requester re-sends it after a timeout); nothing is inferred from
    the name."""

    def register(cls: A) -> A:
        key = (ontology, name)
        if key in _actions and _actions[key].__qualname__ != cls.__qualname__:
            raise ValueError(f"action {name!r} already registered in ontology {ontology!r}")
        cls.action_name = name
        cls.ontology_name = ontology
        cls.reply_model = reply
        cls.group = group or ontology
        cls.idempotent = idempotent
        _actions[key] = cls
        return cls

    return register


def lookup(ontology: str, name: str) -> type[Action]:
    try:
        return _actions[(ontology, name)]
    except KeyError:
        known = sorted(n for (o, n) in _actions if o == ontology)
        if not known:
            raise ContentError(f"unknown ontology {ontology!r}") from None
        raise ContentError(
            f"unknown action {name!r} in ontology {ontology!r} (known: {', '.join(known)})"
        ) from None


def actions(ontology: str | None = None) -> dict[str, type[Action]]:
    return {n: c for (o, n), c in _actions.items() if ontology is None or o == ontology}


def ontologies() -> set[str]:
    return {o for (o, _) in _actions}


def _errors_text(err: ValidationError) -> str:
    parts = []
    for e in err.errors():
        loc = ".".join(str(x) for x in e["loc"]) or "(content)"
        parts.append(f"{loc}: {e['msg']}")
    return "; ".join(parts)


def parse_json(body: str | None) -> Any:
    if body is None or body == "":
        return {}
    try:
        return json.loads(body)
    except json.JSONDecodeError as e:
        raise ContentError(f"malformed JSON content: {e.msg} at position {e.pos}") from None


def validate(model: type[Content], data: Any) -> Content:
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise ContentError(f"invalid content for {model.__name__}: {_errors_text(e)}") from None


def decode_request(ontology: str, name: str, body: str | None) -> Action:
    model = lookup(ontology, name)
    return validate(model, parse_json(body))  # type: ignore[return-value]


def encode(content: Content | None) -> str:
    # never an empty body: a message without one is not delivered over XMPP
    return "{}" if content is None else content.model_dump_json()
