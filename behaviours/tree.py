"""Behaviour-tree composites and decorators beside the FSM, on paper 002's contract: each is a
Behaviour (it ends ok, the terminal condition, or with an error and its reason), so an FSM state
may be a tree and a tree may hold FSMs.

    patrol = Sequence("patrol", [GoTo("kitchen"), Selector("look", [FindLamp(), Retry(Relocalize(), 2)]),
                                 Timeout(TakePicture(), 10.0)])
    fsm.add_state("s2", patrol)

- Sequence: children in order; the first error ends it with that error; ok when all are ok.
- Selector (fallback): children in order until one is ok; an error when all fail (every reason).
- Parallel: children at once; `policy` "all" (ok when all are ok, ends at the first error) or
  "one" (ok at the first ok, an error when all fail); the others are cancelled when it decides.
- Timeout, Retry, Inverter: decorators of one child.

Children share the memory of the context they run in. A composite's `current` names the child
running now (py_trees-style introspection for the trace and debugging).
"""
from __future__ import annotations

import asyncio
from typing import Any, Literal

from .behaviour import Behaviour, Outcome
from .pause import run_pausable


class Composite(Behaviour):
    def __init__(self, name: str | None, children: list[Behaviour], **kw: Any):
        super().__init__(name, **kw)
        if not children:
            raise ValueError(f"{type(self).__name__} {name!r} needs at least one child")
        self.children = list(children)
        self.current: str | None = None

    async def _child(self, child: Behaviour) -> Outcome:
        self.current = child.name
        self.ctx.trace("state", event="enter", fsm=self.name, state=child.name)
        return await child.run(self.ctx)


class Sequence(Composite):
    async def _loop(self) -> Outcome:
        last: Outcome | None = None
        for child in self.children:
            last = await self._child(child)
            if last.error:
                return Outcome(False, f"{child.name}: {last.reason}", last.value, self.name)
        return Outcome(True, "", last.value if last is not None else None, self.name)


class Selector(Composite):
    async def _loop(self) -> Outcome:
        reasons = []
        for child in self.children:
            out = await self._child(child)
            if out.ok:
                return Outcome(True, "", out.value, self.name)
            reasons.append(f"{child.name}: {out.reason}")
        return Outcome(False, "every choice failed (" + "; ".join(reasons) + ")", None, self.name)


class Parallel(Composite):
    def __init__(self, name: str | None, children: list[Behaviour], policy: Literal["all", "one"] = "all",
                 **kw: Any):
        super().__init__(name, children, **kw)
        if policy not in ("all", "one"):
            raise ValueError(f"Parallel policy is 'all' or 'one', not {policy!r}")
        self.policy = policy

    async def _loop(self) -> Outcome:
        self.current = ",".join(c.name for c in self.children)
        tasks = {asyncio.ensure_future(c.run(self.ctx)): c for c in self.children}
        pending, outcomes = set(tasks), {}
        try:
            while pending:
                done, pending = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
                for t in done:
                    out = outcomes[tasks[t].name] = t.result()
                    if self.policy == "all" and out.error:
                        return Outcome(False, f"{tasks[t].name}: {out.reason}", out.value, self.name)
                    if self.policy == "one" and out.ok:
                        return Outcome(True, "", out.value, self.name)
        finally:
            for t in pending:
                t.cancel()
            if pending:
                await asyncio.gather(*pending, return_exceptions=True)
        if self.policy == "all":
            return Outcome(True, "", {n: o.value for n, o in outcomes.items()}, self.name)
        return Outcome(False, "every branch failed (" + "; ".join(f"{n}: {o.reason}" for n, o in outcomes.items())
                       + ")", None, self.name)


class Decorator(Behaviour):
    def __init__(self, child: Behaviour, name: str | None = None, **kw: Any):
        super().__init__(name or f"{type(self).__name__.lower()}({child.name})", **kw)
        self.child = child


class Timeout(Decorator):
    """The child, bounded: an error "timeout after S s" when it runs longer (it is cancelled). Time the
    task spends paused (behaviours/pause.py) does not count, as for a behaviour's own timeout."""

    def __init__(self, child: Behaviour, seconds: float, name: str | None = None):
        super().__init__(child, name)
        self.seconds = seconds

    async def _loop(self) -> Outcome:
        try:
            return await run_pausable(self.child.run(self.ctx), self.seconds, self.ctx.pause)
        except asyncio.TimeoutError:
            return Outcome(False, f"{self.child.name}: timeout after {self.seconds:g}s", None, self.name)


class Retry(Decorator):
    """The child again after an error, up to `attempts` runs in all, `delay` seconds apart."""

    def __init__(self, child: Behaviour, attempts: int, delay: float = 0.0, name: str | None = None):
        super().__init__(child, name)
        if attempts < 1:
            raise ValueError("Retry needs attempts >= 1")
        self.attempts, self.delay = attempts, delay

    async def _loop(self) -> Outcome:
        for attempt in range(1, self.attempts + 1):
            out = await self.child.run(self.ctx)
            if out.ok:
                return Outcome(True, "", out.value, self.name)
            if attempt < self.attempts:
                await asyncio.sleep(self.delay)
        return Outcome(False, f"{self.child.name} failed {self.attempts} times, last: {out.reason}", out.value,
                       self.name)


class Inverter(Decorator):
    """Ok when the child fails, an error when it succeeds (e.g. "the path is NOT blocked")."""

    async def _loop(self) -> Outcome:
        out = await self.child.run(self.ctx)
        if out.ok:
            return Outcome(False, f"{self.child.name} succeeded", out.value, self.name)
        return Outcome(True, "", out.value, self.name)
