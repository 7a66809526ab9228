"""Warm workers: sandboxed processes started ahead of time, so a hand-off costs no interpreter start.

Starting `python -m agents.runtime` and importing SPADE takes most of a second; a Dynamic or
Cloud Agent started that way makes its user wait for it. A Core or the Platform keeps `size` such
processes idle instead: each started exactly like a cold one (agents/process.py `AgentProcess`: its
own fresh uid, run directory `NNNN-.warm`, rlimits, new session, parent-death signal, the sandbox
it applies to itself), with the runtime imported, blocked reading its spec. A hand-off takes one
(`AgentProcess.start` with `pool=`), moves the package into its directory and sends the spec: the
worker becomes that Dynamic/Cloud Agent and is never used again (one process per RApp run).

The pool refills in the background shortly after each hand-off, each new worker importing at a
lower priority until its own hand-off gives it its parent's (REFILL_NICE). A worker that died while idle is
reaped and replaced (after a back-off, should workers keep dying), never handed a RApp. `close()`
kills and reaps the idle workers and removes their directories.

With `hold_running=True` a worker handed a run still counts against `size` until its run ends, and
the pool refills then: the pool's processes, idle or running, are never more than `size`. A Core,
which runs one RApp at a time, keeps so one process instead of two while a RApp runs (a warm
refill there would wait out the whole run; 60-75 MB Pss each, bench/RESULTS.md "fleet memory");
a Platform sized to its robots holds one Cloud process per robot, not two, through a burst.

With `login=` (the Platform's Cloud workers) each worker also gets an account of its own before it
starts (`await login()`, an agents/identity.py Identity) and logs in while idle: the run it is
handed (`AgentProcess.start(worker=...)`, its spec naming that account) costs no login. In a fleet's
burst of 20 Cloud Agent starts the logins were most of a start (18-181 ms of CPU-starved XMPP
round trips, bench/RESULTS.md). A worker let go idle has its account removed (`forget`).
"""
from __future__ import annotations

import asyncio
import itertools
import logging
import shutil
from collections import deque
from pathlib import Path

from .priority import may_raise_priority
from .process import AgentProcess, Limits, check_module_names
from .sandbox import Sandbox

log = logging.getLogger("rapp.warm")
MAX_BACKOFF_S = 30.0
# a refill waits this long after a hand-off: the new worker's start and imports would otherwise slow
# the hand-off it follows (bench/handoff.py measures the hand-off; bench/RESULTS.md has the figures)
REFILL_AFTER_S = 0.5
# a refill's worker imports at this lower priority (nice increment, for its threads and its session's
# scheduling group: agents/priority.py) until its own hand-off: after a burst of hand-offs the pool
# refills many at once (~1 s of CPU each), which competes with the runs just started (bench/fleet.py,
# start_cloud_agent). The lowest nice: each refill is a group of its own, so many of them together
# still outweigh the Platform at a middle value (bench/RESULTS.md, the fleet's first seconds). A worker
# handed a run before its imports are done finishes them at its parent's
# priority, no later than a cold start would (a hand-off waits for a just-started refill to have lowered
# itself first: agents/process.py CONFINED_WITHIN_S). The first fill runs at normal priority: nothing is
# waiting for a hand-off yet, and the owner waits for it.
REFILL_NICE = 19


class WarmPool:
    def __init__(self, workdir: str | Path, settings, *, size: int = 1, limits: Limits = Limits(),
                 sandbox: Sandbox | None = None, preload: tuple[str, ...] = (), refill_nice: int = REFILL_NICE,
                 login=None, forget=None, hold_running: bool = False):
        if not isinstance(size, int) or size < 0:
            raise ValueError(f"warm_workers must be a whole number >= 0, not {size!r}")
        self.workdir, self.settings, self.size = Path(workdir), settings, size
        self.limits, self.sandbox = limits, sandbox or Sandbox()
        self.preload = check_module_names(preload)  # modules workers import too, ahead of time (agents/runtime.py)
        self.login, self.forget = login, forget  # async: a new worker's account / remove an idle one's
        # only where the hand-off can raise it back (root, as the sandbox needs, or RLIMIT_NICE)
        self.refill_nice = refill_nice if refill_nice and may_raise_priority() else 0
        self._idle: deque[AgentProcess] = deque()
        self.hold_running = hold_running
        self._running: set[AgentProcess] = set()  # handed a run that has not ended (hold_running only)
        self._serial = itertools.count(1)
        self._filler: asyncio.Task | None = None
        self._soon: asyncio.TimerHandle | None = None
        self._closing = asyncio.Event()
        self._discards: set[asyncio.Task] = set()
        self._failures = 0  # workers in a row that died idle or did not start: back off
        self.started = 0  # workers launched
        self.lost = 0  # workers that died while idle

    # -- what a Core / the Platform calls -------------------------------------------------------
    def start(self) -> None:
        """Begin filling the pool (in the background: Popen runs in a thread)."""
        self._closing.clear()
        self._refill()

    def take(self) -> AgentProcess | None:
        """An idle, live worker for one RApp run (the pool refills behind it), or None."""
        while self._idle:
            worker = self._idle.popleft()
            if worker.alive():
                self._failures = 0
                if self.hold_running:
                    self._running.add(worker)
                    worker.exited().add_done_callback(lambda _f, w=worker: self._run_ended(w))
                elif self._soon is None:
                    self._soon = asyncio.get_running_loop().call_later(REFILL_AFTER_S, self._refill)
                return worker
            self._lost(worker, idle=False)
        self._refill()
        return None

    def _run_ended(self, worker: AgentProcess) -> None:
        self._running.discard(worker)
        if self._soon is None and not self._closing.is_set():
            self._soon = asyncio.get_running_loop().call_later(REFILL_AFTER_S, self._refill)

    async def discard(self, worker: AgentProcess) -> None:
        """A worker taken and not handed a run after all: stopped, its account removed."""
        await self._discard(worker)

    async def close(self) -> None:
        """Kill and reap the idle workers, remove their directories; no more refills."""
        self._closing.set()
        if self._soon is not None:
            self._soon.cancel()
            self._soon = None
        if self._filler is not None:
            await self._filler  # a launch in progress finishes, then its worker is discarded
        workers, self._idle = list(self._idle), deque()
        await asyncio.gather(*(self._discard(w) for w in workers), *self._discards)

    # -- what tests and benchmarks look at ---------------------------------------------------------
    @property
    def idle(self) -> list[AgentProcess]:
        return list(self._idle)

    async def wait_ready(self, timeout: float = 60.0) -> None:
        """Until `size` idle workers have imported the runtime (TimeoutError else)."""
        async def ready() -> None:
            while sum(w.ready for w in self._idle) < self.size:
                await asyncio.sleep(0.02)

        await asyncio.wait_for(ready(), timeout)

    # -- filling ---------------------------------------------------------------------------------
    def _refill(self) -> None:
        self._soon = None
        if self._closing.is_set() or self.size == 0 or (self._filler is not None and not self._filler.done()):
            return
        self._filler = asyncio.create_task(self._fill())

    async def _fill(self) -> None:
        while not self._closing.is_set() and len(self._idle) + len(self._running) < self.size:
            if self._failures and await self._backed_off():
                return
            refill = self.started >= self.size
            worker = None
            try:
                login = await self.login() if self.login is not None else None
                worker = AgentProcess("warm", None, self.workdir / f"{next(self._serial):04d}-.warm", self.settings,
                                      self.limits, self.sandbox, preload=self.preload,
                                      nice=self.refill_nice if refill else 0, login=login)
                await worker.start()
            except Exception as e:  # noqa: BLE001 - logged; hand-offs start cold meanwhile
                self._failures += 1
                log.warning("cannot start a warm worker: %s: %s", type(e).__name__, e)
                if worker is not None:
                    await self._forget(worker)
                    await asyncio.to_thread(shutil.rmtree, worker.workdir, ignore_errors=True)
                continue
            self.started += 1
            if self._closing.is_set():
                await self._discard(worker)
                return
            self._idle.append(worker)
            worker.exited().add_done_callback(lambda _f, w=worker: self._lost(w))

    async def _backed_off(self) -> bool:
        """Wait before the next launch after failures; True when the pool closed meanwhile."""
        delay = min(MAX_BACKOFF_S, 0.5 * 2 ** (self._failures - 1))
        try:
            await asyncio.wait_for(self._closing.wait(), delay)
            return True
        except asyncio.TimeoutError:
            return False

    def _lost(self, worker: AgentProcess, idle: bool = True) -> None:
        """A worker that exited before any hand-off: reaped (its exit future), cleaned, replaced."""
        if idle:
            if worker not in self._idle:
                return  # handed a RApp, or discarded: not the pool's any more
            self._idle.remove(worker)
        if self._closing.is_set():
            return
        self.lost += 1
        self._failures += 1
        log.warning("warm worker %s exited while idle (code %s): %s", worker.pid, worker.proc.returncode,
                    worker.stderr_tail(300).strip()[-300:])
        task = asyncio.create_task(self._discard(worker))
        self._discards.add(task)
        task.add_done_callback(self._discards.discard)
        self._refill()

    async def _discard(self, worker: AgentProcess) -> None:
        await worker.stop(grace=0.2)
        await self._forget(worker)
        await asyncio.to_thread(shutil.rmtree, worker.workdir, ignore_errors=True)

    async def _forget(self, worker: AgentProcess) -> None:
        if worker.login is not None and self.forget is not None:
            try:
                await self.forget(worker.login)
            except Exception as e:  # noqa: BLE001 - the owner's ledger still lists it for its next sweep
                log.warning("cannot remove warm worker %s's account: %s", worker.pid, e)
