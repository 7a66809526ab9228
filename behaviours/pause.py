"""A task's pause (paper 003's emergency stop as the task sees it): while paused, behaviours do not
start their next iteration and FSMs do not enter their next state; a behaviour's timeout does not
count paused time, up to an allowance (`PAUSE_ALLOWANCE_S`): a task paused for ever still ends. The
running step is suspended where it waits (its robot motions are held by the Core), not failed. The
Dynamic Agent's runtime pauses and resumes it on the Core's notices."""
from __future__ import annotations

import asyncio
import time
from typing import Awaitable, TypeVar

PAUSE_ALLOWANCE_S = 600.0


def charged_seconds(elapsed_s: float, paused_s: float, allowance_s: float = PAUSE_ALLOWANCE_S) -> float:
    """Seconds that count against a time limit after `elapsed_s`, `paused_s` of them paused: a pause
    stops the clock for at most `allowance_s` in all (10 minutes), beyond that it counts like work, so
    a robot stopped for ever (or stopping again and again) still ends its task."""
    return elapsed_s - min(paused_s, allowance_s)


class PauseGate:
    def __init__(self) -> None:
        self._running = asyncio.Event()
        self._running.set()
        self.reason: str | None = None
        self._since: float | None = None
        self._paused_total = 0.0

    @property
    def paused(self) -> bool:
        return self.reason is not None

    def pause(self, reason: str) -> None:
        if self.reason is None:
            self._since = time.monotonic()
        self.reason = reason
        self._running.clear()

    def resume(self) -> None:
        if self._since is not None:
            self._paused_total += time.monotonic() - self._since
        self.reason, self._since = None, None
        self._running.set()

    def paused_seconds(self) -> float:
        """Seconds spent paused so far (the current pause included)."""
        now = 0.0 if self._since is None else time.monotonic() - self._since
        return self._paused_total + now

    async def wait(self) -> None:
        """Return at once when running, else when resumed."""
        if self.reason is not None:
            await self._running.wait()


T = TypeVar("T")


async def run_pausable(coro: Awaitable[T], timeout: float, gate: PauseGate | None,
                       allowance_s: float = PAUSE_ALLOWANCE_S) -> T:
    """`coro` with a timeout that stops counting while `gate` is paused, for at most `allowance_s`
    (TimeoutError when it expires; while paused only once the allowance is spent too)."""
    if gate is None:
        return await asyncio.wait_for(coro, timeout)
    task = asyncio.ensure_future(coro)
    loop = asyncio.get_running_loop()
    start, paused0 = loop.time(), gate.paused_seconds()
    try:
        while True:
            paused = gate.paused_seconds() - paused0
            left = timeout - charged_seconds(loop.time() - start, paused, allowance_s)
            if left <= 0 and (not gate.paused or paused >= allowance_s):
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
                raise asyncio.TimeoutError
            done, _ = await asyncio.wait({task}, timeout=max(left, 0.2))
            if done:
                return task.result()
    except asyncio.CancelledError:
        task.cancel()
        raise
