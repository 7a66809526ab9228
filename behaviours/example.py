"""Worked example: patrol two points, with a sub-FSM that retries a flaky measurement.

    python -m behaviours.example

The top FSM goes: go_a -> measure (sub-FSM) -> go_b -> done. The sub-FSM `measure` takes a
reading; if the reading fails (error condition) it waits and retries, up to three times.
"""
from __future__ import annotations

import asyncio
import random

from .behaviour import Behaviour, OneShot
from .fsm import FSM


class GoTo(Behaviour):
    """Moves a 1-D position towards a target at 1 unit per iteration (the transition function)."""

    period = 0.01

    def __init__(self, target: float, name: str):
        super().__init__(name)
        self.target = target

    async def transition(self) -> None:
        pos = self.memory.get("pos", 0.0)
        step = max(-1.0, min(1.0, self.target - pos))
        self.memory["pos"] = pos + step

    def terminal(self) -> bool:
        return bool(abs(self.memory.get("pos", 0.0) - self.target) < 1e-9)


class Read(OneShot):
    """A sensor read that fails at random: the error condition reports it."""

    def __init__(self, rng: random.Random):
        super().__init__("read")
        self.rng = rng

    async def action(self) -> float:
        self.memory["tries"] = self.memory.get("tries", 0) + 1
        value = self.rng.random()
        self.memory["reading"] = value if value > 0.5 else None
        return value

    def error(self) -> str | None:
        if self.iterations and self.memory.get("reading") is None:
            return "reading below noise floor"
        return None


class Pause(Behaviour):
    """Waits one period."""

    period = 0.01

    def terminal(self) -> bool:
        return self.iterations >= 1


class Report(OneShot):
    async def action(self) -> float:
        reading: float = self.memory["reading"]  # Read set it: the FSM reaches "ok" only without error
        return reading


def build(seed: int = 1) -> FSM:
    rng = random.Random(seed)
    measure = FSM("measure", initial="read")
    measure.add_state("read", Read(rng))
    measure.add_state("pause", Pause("pause"))
    measure.add_state("ok", Report("ok"), final=True)
    measure.add_transition("read", "ok")
    measure.add_transition("read", "pause", on_error=True, when=lambda m, o: m["tries"] < 3)
    measure.add_transition("pause", "read")

    patrol = FSM("patrol", initial="go_a")
    patrol.add_state("go_a", GoTo(3, "go_a"))
    patrol.add_state("measure", measure)
    patrol.add_state("go_b", GoTo(-2, "go_b"))
    patrol.add_final("go_b")
    patrol.add_transition("go_a", "measure")
    patrol.add_transition("measure", "go_b")
    return patrol


async def main() -> None:
    fsm = build()
    outcome = await fsm.run()
    print("outcome:", outcome)
    measure = fsm.states["measure"]
    assert isinstance(measure, FSM)
    print("states:", fsm.history, "sub-FSM states:", measure.history)


if __name__ == "__main__":
    asyncio.run(main())
