"""Ontology queries over a small class hierarchy of household objects (data/household_ontology.json,
class -> parent)."""
from __future__ import annotations

import json
from functools import lru_cache

from ontology.services.knowledge import ClassList, IsSubclass, IsSubclassOf, SubclassesOf, SuperclassesOf
from ontology.errors import ErrorCode

from .context import DATA_DIR, ServiceContext
from .errors import ServiceError


@lru_cache(maxsize=1)
def hierarchy() -> dict[str, str | None]:
    return json.loads((DATA_DIR / "household_ontology.json").read_text())


def _known(cls: str) -> str:
    h = hierarchy()
    if cls in h:
        return cls
    for k in h:  # case-insensitive fallback
        if k.lower() == cls.lower():
            return k
    raise ServiceError(f"unknown class {cls!r} in the household ontology", ErrorCode.UNKNOWN_CLASS)


def superclasses(cls: str, recursive: bool = True) -> list[str]:
    h, out, c = hierarchy(), [], _known(cls)
    while h[c] is not None:
        c = h[c]
        out.append(c)
        if not recursive:
            break
    return out


def subclasses(cls: str, recursive: bool = True) -> list[str]:
    c = _known(cls)
    h = hierarchy()
    direct = sorted(k for k, p in h.items() if p == c)
    if not recursive:
        return direct
    out = []
    for d in direct:
        out.append(d)
        out.extend(subclasses(d, True))
    return out


def subclasses_of(req: SubclassesOf, ctx: ServiceContext) -> ClassList:
    return ClassList(classes=subclasses(req.cls, req.recursive))


def superclasses_of(req: SuperclassesOf, ctx: ServiceContext) -> ClassList:
    return ClassList(classes=superclasses(req.cls, req.recursive))


def is_subclass_of(req: IsSubclassOf, ctx: ServiceContext) -> IsSubclass:
    parent = _known(req.parent)
    return IsSubclass(result=parent in superclasses(req.child))
