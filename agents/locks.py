"""Resource locks of paper 003: lock (wait), try-lock (fail at once), free, per device.

A lock is held by one owner at a time (a Dynamic Agent's JID, or a Core behaviour's name) and is
re-entrant for that owner, so a RApp that locked the base can still send motion commands.
"""
from __future__ import annotations

import asyncio
import contextlib
from dataclasses import dataclass, field

from ontology.robot_actions import DEVICES, facts

__all__ = ["DEVICES", "LockError", "ResourceLocks", "device_of"]


def device_of(action_name: str) -> str | None:
    """The device a robot-API command locks while it runs (its row in ontology/robot_actions.py);
    None for commands that need no exclusive use."""
    return facts(action_name).device


class LockError(RuntimeError):
    pass


@dataclass
class _Lock:
    holder: str | None = None
    depth: int = 0
    released: asyncio.Event = field(default_factory=asyncio.Event)


class ResourceLocks:
    def __init__(self, devices=DEVICES):
        self._locks = {d: _Lock() for d in devices}

    def _get(self, resource: str) -> _Lock:
        try:
            return self._locks[resource]
        except KeyError:
            raise LockError(f"unknown resource {resource!r} (known: {', '.join(self._locks)})") from None

    def holder(self, resource: str) -> str | None:
        return self._get(resource).holder

    def try_lock(self, resource: str, owner: str) -> bool:
        lock = self._get(resource)
        if lock.holder in (None, owner):
            lock.holder, lock.depth = owner, lock.depth + 1
            lock.released.clear()
            return True
        return False

    async def lock(self, resource: str, owner: str, timeout: float | None = None) -> bool:
        """Wait until the resource is free (or already ours); False on timeout."""
        loop = asyncio.get_running_loop()
        deadline = None if timeout is None else loop.time() + timeout
        lock = self._get(resource)
        while not self.try_lock(resource, owner):
            remaining = None if deadline is None else deadline - loop.time()
            if remaining is not None and remaining <= 0:
                return False
            try:
                await asyncio.wait_for(lock.released.wait(), remaining)
            except asyncio.TimeoutError:
                return False
        return True

    def free(self, resource: str, owner: str) -> None:
        lock = self._get(resource)
        if lock.holder != owner:
            raise LockError(f"{resource} is held by {lock.holder or 'nobody'}, not by {owner}")
        lock.depth -= 1
        if lock.depth <= 0:
            lock.holder, lock.depth = None, 0
            lock.released.set()

    def free_all(self, owner: str) -> list[str]:
        freed = []
        for name, lock in self._locks.items():
            if lock.holder == owner:
                lock.holder, lock.depth = None, 0
                lock.released.set()
                freed.append(name)
        return freed

    @contextlib.asynccontextmanager
    async def hold(self, resource: str | None, owner: str, timeout: float | None = None):
        if resource is None:
            yield
            return
        if not await self.lock(resource, owner, timeout):
            raise LockError(f"{resource} is busy (held by {self.holder(resource)})")
        try:
            yield
        finally:
            self.free(resource, owner)
