"""A typed blackboard for a RApp's behaviours (as py_trees' blackboard): the task declares each key
with its type and the states that may write it; reading an undeclared key, or one not written yet
(and without a default), is an error naming the key; every write is traced with its writer.

    class Patrol(Task):
        keys = {
            "home": Key(HomeInfo, writers=["get_home"]),
            "visited": Key(list, default=[]),          # any state may write it
        }

        async def get_home(self, memory):
            self.bb.home = await self.platform.home_get_info(home_id="home")

The values live in the task's `memory` dict, so `memory["home"]` (the untyped view older RApps
use) and `self.bb.home` are the same value.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any, Callable

from pydantic import TypeAdapter, ValidationError

from ontology.trace import RecordKind

_NO_DEFAULT = object()


class BlackboardError(KeyError):
    def __str__(self) -> str:  # KeyError would quote the whole message
        return str(self.args[0])


@dataclass
class Key:
    type: Any = Any
    writers: list[str] = field(default_factory=list)  # states (behaviour names) allowed to write; [] = any
    default: Any = _NO_DEFAULT
    doc: str = ""


class Blackboard:
    def __init__(self, keys: dict[str, Key], memory: dict[str, Any], *, writer: Callable[[], str] = lambda: "",
                 trace: Callable[..., None] | None = None):
        object.__setattr__(self, "_keys", dict(keys))
        object.__setattr__(self, "_memory", memory)
        object.__setattr__(self, "_writer", writer)
        object.__setattr__(self, "_trace", trace)
        object.__setattr__(self, "_adapters", {k: TypeAdapter(v.type) for k, v in keys.items()})
        for name, key in keys.items():
            if key.default is not _NO_DEFAULT and name not in memory:
                memory[name] = copy.deepcopy(key.default)

    def _key(self, name: str) -> Key:
        keys: dict[str, Key] = self._keys
        try:
            return keys[name]
        except KeyError:
            raise BlackboardError(f"blackboard key {name!r} is not declared (declared: "
                                  f"{', '.join(sorted(self._keys)) or 'none'})") from None

    def get(self, name: str) -> Any:
        self._key(name)
        if name not in self._memory:
            raise BlackboardError(f"blackboard key {name!r} has not been written yet")
        return self._memory[name]

    def set(self, name: str, value: Any) -> None:
        key, writer = self._key(name), self._writer()
        if key.writers and writer not in key.writers:
            raise BlackboardError(f"state {writer!r} may not write blackboard key {name!r} "
                                  f"(writers: {', '.join(key.writers)})")
        try:
            value = self._adapters[name].validate_python(value)
        except ValidationError as e:
            raise TypeError(f"blackboard key {name!r} takes {key.type!r}: {e.errors()[0]['msg']}") from None
        self._memory[name] = value
        if self._trace is not None:
            self._trace(RecordKind.BLACKBOARD, key=name, value=repr(value)[:200], writer=writer)

    def __getattr__(self, name: str) -> Any:
        return self.get(name)

    def __setattr__(self, name: str, value: Any) -> None:
        self.set(name, value)

    def __contains__(self, name: str) -> bool:
        return name in self._keys and name in self._memory

    def declared(self) -> dict[str, Key]:
        return dict(self._keys)
