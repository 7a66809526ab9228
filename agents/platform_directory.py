"""Several Platform agents serving one domain: the primary's directory of Platform agents and the
clients' load-aware choice (the messages they exchange: ontology/platform_directory.py).

- The primary Platform keeps users, tokens, Cloud Agents and every stateful service (maps, obstacle
  marks, home descriptions, learned objects, e-mail, cognitive history, noise profiles).
- A replica (`PlatformAgent(primary="platform")`) serves only the stateless CPU-bound services
  (REPLICATED); the primary accepts it only if it names it (`PlatformAgent(replicas=[...])`): a
  replica sees users' tokens and camera images.
- A replica reports to the primary every REPORT_S (`platform_report`: services, capacity = its
  worker processes, outstanding = calls running): the report is its registration and its heartbeat;
  the primary lists replicas heard within STALE_S.
- Tokens: a replica asks the primary (`lookup_token`) and keeps a positive answer TOKEN_CACHE_S; the
  primary tells live replicas of a revocation at once (`token_revoked`), so a revoked token is refused
  on a replica at once, and in any case after TOKEN_CACHE_S (a lost notice).
- Clients (`PlatformChooser`, used by the SDK's PlatformProxy) ask the primary `list_platforms`,
  send REPLICATED services to one of the Platform agents offering them, by power of two choices on
  (reported outstanding + own outstanding) / capacity, and everything else to the primary.
"""
from __future__ import annotations

import asyncio
import hashlib
import random
import time
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass

from ontology.platform_directory import (ONTOLOGY, ListPlatforms, LookupToken, PlatformEntry,  # noqa: F401
                                         PlatformList, PlatformReport, TokenRecord, TokenRevoked)

# stateless services a replica serves (the request carries all they need)
REPLICATED = frozenset({
    "qr_detection", "compute_global_pose", "face_detection", "human_detection",
    "hazard_detection_door_check", "hazard_detection_light_check", "text_to_speech",
})
REPORT_S = 1.0  # a replica's load report period
STALE_S = 3.5  # a replica not heard for this long is not listed
TOKEN_CACHE_S = 2.0  # how long a replica trusts the primary's answer about a token
REFRESH_S = 5.0  # how often a client reads the directory again
RETRY_ABSENT_S = 60.0  # a primary without a directory (an older Platform) is asked again after this


def token_digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


@dataclass
class _Replica:
    jid: str
    services: frozenset[str]
    capacity: int
    outstanding: int
    heard: float  # time.monotonic()


class PlatformDirectory:
    """The primary's list of its replicas (a directory facilitator for Platform agents)."""

    def __init__(self, allowed: set[str]):
        self.allowed = set(allowed)  # bare JIDs of the replicas this primary trusts
        self._replicas: dict[str, _Replica] = {}

    def report(self, jid: str, req: PlatformReport) -> bool:
        """Record a replica's report; False when it is new (or came back after going stale)."""
        old = self._replicas.get(jid)
        fresh = old is not None and time.monotonic() - old.heard <= STALE_S
        self._replicas[jid] = _Replica(jid, frozenset(req.services) & REPLICATED, max(1, req.capacity),
                                       max(0, req.outstanding), time.monotonic())
        return fresh

    def live(self) -> list[_Replica]:
        now = time.monotonic()
        return [r for r in self._replicas.values() if now - r.heard <= STALE_S]

    def entries(self, primary: PlatformEntry) -> list[PlatformEntry]:
        now = time.monotonic()
        return [primary] + [PlatformEntry(jid=r.jid, services=sorted(r.services), capacity=r.capacity,
                                          outstanding=r.outstanding, age_s=round(now - r.heard, 3))
                            for r in self.live()]


class PlatformChooser:
    """A client's choice of Platform agent per service call (see the module docstring).

        chooser = PlatformChooser(agent, primary_jid, token)
        target = await chooser.target("hazard_detection_door_check")
        with chooser.track(target):
            reply = await agent.request(target, request)
    """

    def __init__(self, agent, primary: str, token: str, *, rng: random.Random | None = None):
        self.agent, self.primary, self.token = agent, primary, token
        self.entries: list[PlatformEntry] = []
        self.outstanding: Counter[str] = Counter()  # this client's calls in flight, per Platform agent
        self.chosen: Counter[str] = Counter()
        self._next_refresh = 0.0
        self._refreshing: asyncio.Task | None = None
        self._rng = rng or random.Random()

    async def target(self, action_name: str) -> str:
        if action_name not in REPLICATED:
            return self.primary
        now = time.monotonic()
        if now >= self._next_refresh and self._refreshing is None:
            self._refreshing = asyncio.ensure_future(self._refresh())
        if not self.entries and self._refreshing is not None:
            await asyncio.shield(self._refreshing)  # the first call waits for the directory once
        candidates = [e for e in self.entries if e.primary or action_name in e.services]
        jid = self.choose(candidates) if len(candidates) > 1 else self.primary
        self.chosen[jid] += 1
        return jid

    def choose(self, candidates: list[PlatformEntry]) -> str:
        """Power of two choices on the load per worker (reported + this client's own calls)."""
        pair = self._rng.sample(candidates, 2) if len(candidates) > 2 else list(candidates)
        self._rng.shuffle(pair)  # ties go either way
        return min(pair, key=lambda e: (e.outstanding + self.outstanding[e.jid]) / max(1, e.capacity)).jid

    @contextmanager
    def track(self, jid: str):
        self.outstanding[jid] += 1
        try:
            yield
        finally:
            self.outstanding[jid] -= 1

    def forget(self, jid: str) -> None:
        """A Platform agent that refused to serve (gone, restarted as something else): not chosen
        again until the next read of the directory."""
        self.entries = [e for e in self.entries if e.jid != jid or e.primary]

    async def _refresh(self) -> None:
        from .errors import RequestError

        try:
            reply = await self.agent.request(self.primary, ListPlatforms(token=self.token), timeout=10.0, retries=0)
            self.entries = reply.platforms
            self._next_refresh = time.monotonic() + REFRESH_S
        except RequestError:  # no directory there (an older Platform) or not now: the primary alone
            self.entries = []
            self._next_refresh = time.monotonic() + RETRY_ABSENT_S
        finally:
            self._refreshing = None
