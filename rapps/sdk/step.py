"""`Step(fn)`: the one-shot behaviour that runs one step of a task's FSM."""
from __future__ import annotations

from typing import Any, Awaitable, Callable

from behaviours import OneShot


class Step(OneShot):
    """A one-shot behaviour running `async fn(memory)`; its return value is the outcome value."""

    def __init__(self, fn: Callable[[dict[str, Any]], Awaitable[Any]], name: str | None = None, **kw: Any) -> None:
        super().__init__(name or getattr(fn, "__name__", "step"), **kw)
        self.fn = fn

    async def action(self) -> Any:
        return await self.fn(self.memory)
