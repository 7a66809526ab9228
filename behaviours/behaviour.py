"""The embodied-agent behaviour of paper 002, on asyncio.

A behaviour iterates a transition function at a rate until its terminal condition holds (it ends
normally) or its error condition holds (it ends with that reason). Subclasses override:

    async def transition(self) -> None     one iteration: read inputs and memory, act, update memory
    def terminal(self) -> bool             the task of this behaviour is done
    def error(self) -> str | None          a reason when it cannot go on, else None
    async def on_start(self) / on_end(self, outcome)    optional hooks

`period` is the time between iterations (0: as fast as the event loop allows, still yielding).
`timeout` bounds the whole behaviour (an error "timeout"). `memory` is the agent's internal memory,
shared by all behaviours of one FSM. Nothing here blocks the event loop: put CPU or device work
behind `await asyncio.to_thread(...)` or an async API.
"""
from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from .pause import run_pausable


def exception_text(e: BaseException) -> str:
    """'Type: message' of an error; one without a message (a bare `raise RuntimeError()`, `assert x`)
    says where it was raised instead, its only clue: 'Type at file.py:LINE' (the innermost frame)."""
    text = str(e).strip()
    if text:
        return f"{type(e).__name__}: {text}"
    tb = e.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return type(e).__name__ + (f" at {Path(tb.tb_frame.f_code.co_filename).name}:{tb.tb_lineno}" if tb else "")


@dataclass(frozen=True)
class Outcome:
    """How a behaviour ended: ok (terminal condition) or error with a reason; value is free."""

    ok: bool
    reason: str = ""
    value: Any = None
    behaviour: str = ""

    @property
    def error(self) -> bool:
        return not self.ok


@dataclass
class Context:
    """What a running behaviour sees: its agent (may be None in tests) and the shared memory."""

    agent: Any = None
    memory: dict[str, Any] = field(default_factory=dict)
    tracer: Any = None  # agents.tracing.TraceWriter or None
    pause: Any = None  # behaviours.pause.PauseGate or None: the task's emergency-stop pause

    async def hold(self) -> None:
        """Wait while the task is paused (returns at once otherwise)."""
        if self.pause is not None:
            await self.pause.wait()

    def trace(self, kind: str, **fields: Any) -> None:
        if self.tracer is not None:
            agent = getattr(self.agent, "address", "")
            self.tracer.record(kind, agent=agent, **fields)


class Behaviour:
    period: float = 0.0
    timeout: float | None = None

    def __init__(self, name: str | None = None, *, period: float | None = None,
                 timeout: float | None = None):
        self.name = name or type(self).__name__
        if period is not None:
            self.period = period
        if timeout is not None:
            self.timeout = timeout
        self.ctx: Context = Context()
        self.iterations = 0
        self.result: Any = None  # set by subclasses; becomes Outcome.value

    # -- contract ---------------------------------------------------------------------------
    async def transition(self) -> None:
        """One iteration of the transition function. Default: nothing (a pure wait)."""

    def terminal(self) -> bool:
        return False

    def error(self) -> str | None:
        return None

    async def on_start(self) -> None:
        pass

    async def on_end(self, outcome: Outcome) -> None:
        pass

    # -- conveniences -----------------------------------------------------------------------
    @property
    def memory(self) -> dict[str, Any]:
        return self.ctx.memory

    @property
    def agent(self) -> Any:
        return self.ctx.agent

    # -- engine -----------------------------------------------------------------------------
    async def run(self, ctx: Context | None = None) -> Outcome:
        """Iterate until terminal or error; exceptions in the transition end it as errors."""
        self.ctx = ctx or self.ctx
        self.iterations = 0
        self.result = None
        try:
            if self.timeout is not None:  # paused time does not count
                outcome: Outcome = await run_pausable(self._loop(), self.timeout, self.ctx.pause)
            else:
                outcome = await self._loop()
        except asyncio.TimeoutError:
            outcome = Outcome(False, f"timeout after {self.timeout:g}s", behaviour=self.name)
        await self.on_end(outcome)
        return outcome

    async def _loop(self) -> Outcome:
        try:
            await self.on_start()
            while True:
                reason = self.error()
                if reason:
                    return Outcome(False, reason, self.result, self.name)
                if self.terminal():
                    return Outcome(True, "", self.result, self.name)
                await self.ctx.hold()
                await self.transition()
                self.iterations += 1
                await asyncio.sleep(self.period)
        except asyncio.CancelledError:
            raise
        except Exception as e:  # noqa: BLE001 - a failing transition is the behaviour's error
            return Outcome(False, exception_text(e), self.result, self.name)


class OneShot(Behaviour):
    """A behaviour whose transition runs once: `async def action(self)` returns the value."""

    async def action(self) -> Any:
        raise NotImplementedError

    async def transition(self) -> None:
        self.result = await self.action()

    def terminal(self) -> bool:
        return self.iterations >= 1


class Idle(Behaviour):
    """The default behaviour of paper 002: do nothing, at a slow rate, until something applies."""

    period = 0.05

    def terminal(self) -> bool:
        return self.iterations >= 1


class Wait(Behaviour):
    """Ends when `predicate(memory)` holds (checked every `period` seconds)."""

    def __init__(self, predicate: Callable[[dict[str, Any]], object], name: str | None = None, **kw: Any):
        super().__init__(name, **kw)
        self.predicate = predicate

    def terminal(self) -> bool:
        return bool(self.predicate(self.memory))


def active_path(behaviour: Behaviour) -> list[str]:
    """The names of the states/children running now, outermost first (FSMs and composites keep
    `current`; a leaf has none): e.g. ["navigate", "move_leg"]."""
    path: list[str] = []
    b: Any = behaviour
    while b is not None and getattr(b, "current", None):
        path.append(b.current)
        b = getattr(b, "states", {}).get(b.current) or next(
            (c for c in getattr(b, "children", ()) if c.name == b.current), None)
    return path
