"""Resource locks of paper 003 (sec. V-B): lock (wait), try-lock (fail at once), free, per device,
and inheritance.

"Agents can only be locked by one flexible program at a time, but these usage authorizations can be
inherited" (paper 003, sec. V-B); a flexible program is made of functional blocks, "often FPs used as
functional blocks within other FPs" (sec. V-G), and keeps "a list of currently owned resources"
(sec. V-E). So here:

- A lock has an owner (a Dynamic Agent's JID, or a Core behaviour's name) and is re-entrant for it,
  so a RApp that locked the base can still send motion commands.
- The one using it may hand its authorization down (`lend`) to a program acting for it (a heir): the
  heir is then the only one that may use the device, the owner keeps owning it, and gets it back
  when the heir gives it back (`give_back`, or the heir's last `free`). A heir may lend on in turn
  (a chain: owner, heir, heir's heir...). Still one user at a time: while its heir acts, the owner
  is refused (try-lock) or waits (lock), as anyone else.
- `free_all(x)` (x ended) drops x and whatever it lent on: the authorization goes back to whoever
  lent it to x, or the device is free when x owned it.
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
    chain: list[list] = field(default_factory=list)  # [[name, depth], ...]: the owner first, the user last
    changed: asyncio.Event = field(default_factory=asyncio.Event)  # set (and replaced) at every change of user

    def user(self) -> str | None:
        return self.chain[-1][0] if self.chain else None

    def names(self) -> list[str]:
        return [name for name, _ in self.chain]

    def notify(self) -> None:
        self.changed.set()
        self.changed = asyncio.Event()


class ResourceLocks:
    def __init__(self, devices=DEVICES):
        self._locks = {d: _Lock() for d in devices}

    def _get(self, resource: str) -> _Lock:
        try:
            return self._locks[resource]
        except KeyError:
            raise LockError(f"unknown resource {resource!r} (known: {', '.join(self._locks)})") from None

    def holder(self, resource: str) -> str | None:
        """Who may use the resource now: its owner, or the heir acting for it."""
        return self._get(resource).user()

    def owner(self, resource: str) -> str | None:
        """Who locked it (the first of the chain), whoever uses it now."""
        chain = self._get(resource).chain
        return chain[0][0] if chain else None

    def chain(self, resource: str) -> tuple[str, ...]:
        """Owner first, then each heir in turn; the last one is the user."""
        return tuple(self._get(resource).names())

    def try_lock(self, resource: str, owner: str) -> bool:
        lock = self._get(resource)
        if not lock.chain:
            lock.chain.append([owner, 1])
            return True
        if lock.user() == owner:
            lock.chain[-1][1] += 1
            return True
        return False

    async def lock(self, resource: str, owner: str, timeout: float | None = None) -> bool:
        """Wait until the resource is free (or ours to use again); False on timeout."""
        loop = asyncio.get_running_loop()
        deadline = None if timeout is None else loop.time() + timeout
        lock = self._get(resource)
        while True:
            changed = lock.changed  # taken before trying: a change in between is not missed
            if self.try_lock(resource, owner):
                return True
            remaining = None if deadline is None else deadline - loop.time()
            if remaining is not None and remaining <= 0:
                return False
            try:
                await asyncio.wait_for(changed.wait(), remaining)
            except asyncio.TimeoutError:
                return False

    def free(self, resource: str, owner: str) -> None:
        """One hold less; at the last, the device is free (its owner) or goes back to whoever lent it
        (a heir)."""
        lock = self._get(resource)
        if lock.user() != owner:
            raise LockError(f"{resource} is held by {lock.user() or 'nobody'}, not by {owner}")
        lock.chain[-1][1] -= 1
        if lock.chain[-1][1] <= 0:
            lock.chain.pop()
            lock.notify()

    def lend(self, resource: str, giver: str, heir: str) -> None:
        """Hand the use of `resource` down from its user `giver` to `heir` (paper 003's inheritance)."""
        lock = self._get(resource)
        if lock.user() != giver:
            raise LockError(f"{giver} cannot lend {resource}: it is used by {lock.user() or 'nobody'}")
        if heir in lock.names():
            raise LockError(f"{heir} already holds {resource} (chain: {' > '.join(lock.names())})")
        lock.chain.append([heir, 1])
        lock.notify()

    def give_back(self, resource: str, heir: str) -> str:
        """The heir is done: the one who lent it uses the resource again (returned)."""
        lock = self._get(resource)
        if lock.user() != heir or len(lock.chain) < 2:
            raise LockError(f"{heir} has not inherited {resource} (chain: {' > '.join(lock.names()) or 'free'})")
        lock.chain.pop()
        lock.notify()
        return lock.user()

    def free_all(self, owner: str) -> list[str]:
        """Drop `owner` and everything it lent on, from every lock; the resources it owned."""
        freed = []
        for name, lock in self._locks.items():
            names = lock.names()
            if owner in names:
                del lock.chain[names.index(owner):]
                lock.notify()
                if not lock.chain:
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

    @contextlib.asynccontextmanager
    async def acting_for(self, resource: str, heir: str, timeout: float | None = None):
        """Use `resource` as `heir`: inherited from its present user when it is held (given back at
        the end), else locked as its own. Yields the one it was inherited from (None: locked)."""
        giver = self.holder(resource)
        if giver is None:
            async with self.hold(resource, heir, timeout):
                yield None
            return
        self.lend(resource, giver, heir)
        try:
            yield giver
        finally:
            if heir in self.chain(resource):  # not dropped meanwhile (the giver ended)
                del self._get(resource).chain[self.chain(resource).index(heir):]
                self._get(resource).notify()
