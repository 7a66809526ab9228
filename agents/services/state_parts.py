"""The parts of the Platform's state a pooled service call takes to its worker process and gives back
(agents/services/pool.py): state stays in the Platform, a call carries only the caller's own entries
it needs. The service table (agents/services/registry.py) names, per pooled service, a reader per
store it reads and the stores it writes; this module says how each store travels.

A reader returns the part of one store to take (a plain, picklable dict), or None to take none of it
(the worker's service then finds that store empty). Service modules are imported inside the
functions: the registry imports this module, and one service module must not import them all.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from .context import ServiceContext


def _same(part: Any) -> Any:
    return part


def _plain(store: Any) -> Any:
    return dict(store) if isinstance(store, dict) else store


@dataclass(frozen=True)
class Travel:
    """How a named store (ServiceState.store) crosses to a worker and back."""

    unpack: Callable[[Any], Any] = _same  # worker: the part taken -> the store object the service uses
    pack: Callable[[Any], Any] = _plain  # worker: the store after the call -> the plain part given back
    merge: Callable[[ServiceContext, str, Any], None] | None = None  # Platform: the part given back -> its store


def _objects(part: dict) -> Any:
    from .vision import ObjectModels

    models = ObjectModels()
    models.models = part
    return models


def _homes(part: dict) -> Any:
    from .home import HomeStore

    return HomeStore.holding(part)


def _gallery(part: dict) -> Any:
    from .faces import FaceGallery

    gallery = FaceGallery()
    gallery.people = part
    return gallery


def _put_faces(ctx: ServiceContext, name: str, part: dict) -> None:
    from .faces import gallery

    for person, descriptors in part.get(ctx.user, {}).items():
        gallery(ctx).put(ctx.user, person, descriptors)


STORES: dict[str, Travel] = {
    "objects": Travel(unpack=_objects),
    "homes": Travel(unpack=_homes),
    "faces": Travel(unpack=_gallery, pack=lambda g: g.people, merge=_put_faces),
    "speech_noise_profiles": Travel(),  # {(user, name): array} both ways
}


def travel(name: str) -> Travel:
    return STORES.get(name, Travel())


def merge(ctx: ServiceContext, name: str, part: Any) -> None:
    """A part a pooled call gave back, into the Platform's state (and so its saved data)."""
    how = travel(name).merge
    if how is not None:
        how(ctx, name, part)
    else:
        ctx.state.store(name, dict).update(part)


# ------------------------------------------------------------------ readers: (request, ctx) -> part
def callers_objects(req, ctx: ServiceContext) -> dict:
    """The caller's learned objects."""
    from .vision import models

    store = models(ctx)
    with store.lock:
        return {ctx.user: dict(store.models.get(ctx.user, {}))}


def named_noise_profile(req, ctx: ServiceContext) -> dict | None:
    """The noise profile the request names, if it names one."""
    if not req.noise_profile:
        return None
    profiles = ctx.state.store("speech_noise_profiles", dict)
    key = (ctx.user, req.noise_profile)
    return {key: profiles[key]} if key in profiles else {}


def rooms_if_asked(req, ctx: ServiceContext) -> dict | None:
    """The rooms of the caller's homes, and nothing else of them, when a sentence has a {room} to fill."""
    from .speech import needs_rooms

    if not needs_rooms(req):
        return None
    from .home import homes

    return {key: info.model_copy(update={"hazards": [], "landmarks": {}, "doors": []})
            for key, info in homes(ctx.state).of_user(ctx.user).items()}


def empty(req, ctx: ServiceContext) -> dict:
    """Nothing of the store: the call only adds to it."""
    return {}


def callers_faces(req, ctx: ServiceContext) -> dict:
    """Every person the caller taught."""
    from .faces import gallery

    return {ctx.user: gallery(ctx).of(ctx.user)}


def named_persons_faces(req, ctx: ServiceContext) -> dict:
    """The samples of the person the request names, if the caller taught them before."""
    from .faces import gallery

    mine = gallery(ctx).of(ctx.user)
    return {ctx.user: {req.name: mine[req.name]} if req.name in mine else {}}
