"""Per-user home descriptions (map id, landmarks, hazard list) kept on the Platform."""
from __future__ import annotations

import logging
import threading

from ontology.services.home import GetHomeInfo, HomeInfo, UploadHomeInfo
from ontology.errors import ErrorCode

from .context import ServiceContext, ServiceState
from .errors import ServiceError

log = logging.getLogger("rapp.platform")


class HomeStore:
    """(user, home_id) -> HomeInfo, thread-safe; kept in `saved` (agents/services/saved.py) if given."""

    KIND = "home"

    def __init__(self, saved=None):
        self._homes: dict[tuple[str, str], HomeInfo] = {}
        self._lock = threading.Lock()
        self._saved = saved
        for rec in saved.records(self.KIND) if saved is not None else ():
            try:
                self._homes[(rec.user, rec.key)] = HomeInfo.model_validate(rec.meta)
            except ValueError as e:  # written by an older layout: that home is left out, not the rest
                log.warning("saved home %r of %s no longer reads: %s", rec.key, rec.user, e)

    def put(self, user: str, info: HomeInfo) -> None:
        if self._saved is not None:
            self._saved.put(self.KIND, user, info.home_id, info.model_dump(mode="json"))
        with self._lock:
            self._homes[(user, info.home_id)] = info

    def get(self, user: str, home_id: str) -> HomeInfo | None:
        with self._lock:
            return self._homes.get((user, home_id))

    def of_user(self, user: str) -> dict[tuple[str, str], HomeInfo]:
        with self._lock:
            return {k: v for k, v in self._homes.items() if k[0] == user}

    @classmethod
    def holding(cls, entries: dict[tuple[str, str], HomeInfo]) -> "HomeStore":
        store = cls()
        store._homes = dict(entries)
        return store

    def rooms(self, user: str) -> list[str]:
        """The names of the rooms of all `user`'s homes."""
        return sorted({r.name for info in self.of_user(user).values() for r in info.rooms})


def homes(state: ServiceState) -> HomeStore:
    return state.store("homes", lambda: HomeStore(state.saved))


def upload_info(req: UploadHomeInfo, ctx: ServiceContext) -> HomeInfo:
    homes(ctx.state).put(ctx.user, req.info)
    return req.info


def get_info(req: GetHomeInfo, ctx: ServiceContext) -> HomeInfo:
    info = homes(ctx.state).get(ctx.user, req.home_id)
    if info is None:
        raise ServiceError(f"no home {req.home_id!r} uploaded for user {ctx.user!r}", ErrorCode.UNKNOWN_HOME)
    return info
