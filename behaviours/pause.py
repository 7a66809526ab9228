"""A task's pause (paper 003's emergency stop as the task sees it): while paused, behaviours do not
start their next iteration and FSMs do not enter their next state; a behaviour's timeout does not
count paused time. The running step is suspended where it waits (its robot motions are held by the
Core), not failed. The Dynamic Agent's runtime pauses and resumes it on the Core's notices."""
from __future__ import annotations

import asyncio
import time


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


async def run_pausable(coro, timeout: float, gate: PauseGate | None):
    """`coro` with a timeout that stops counting while `gate` is paused (TimeoutError when it expires)."""
    if gate is None:
        return await asyncio.wait_for(coro, timeout)
    task = asyncio.ensure_future(coro)
    loop = asyncio.get_running_loop()
    start, paused0 = loop.time(), gate.paused_seconds()
    try:
        while True:
            left = start + timeout + (gate.paused_seconds() - paused0) - loop.time()
            if left <= 0 and not gate.paused:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
                raise asyncio.TimeoutError
            done, _ = await asyncio.wait({task}, timeout=max(left, 0.2))
            if done:
                return task.result()
    except asyncio.CancelledError:
        task.cancel()
        raise
