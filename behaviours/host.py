"""Runs an embodied behaviour (or FSM) as a SPADE behaviour of an agent.

    host = BehaviourHost(task_fsm, memory=agent.memory)
    agent.activate("task", host)          # RappAgent: traced activation
    outcome = await host.outcome          # an asyncio.Future resolved when the behaviour ends
"""
from __future__ import annotations

import asyncio
from typing import Any

from spade.behaviour import OneShotBehaviour

from .behaviour import Behaviour, Context, Outcome
from .pause import PauseGate


class BehaviourHost(OneShotBehaviour):  # type: ignore[misc]  # SPADE ships no type information
    def __init__(self, behaviour: Behaviour, memory: dict[str, Any] | None = None, pause: PauseGate | None = None):
        super().__init__()
        self.behaviour = behaviour
        self.pause = pause  # a behaviours.pause.PauseGate: the task holds while it is paused
        self.shared_memory = memory if memory is not None else {}
        self.outcome: asyncio.Future[Outcome] = asyncio.get_event_loop().create_future()

    async def run(self) -> None:
        ctx = Context(agent=self.agent, memory=self.shared_memory,
                      tracer=getattr(self.agent, "tracer", None), pause=self.pause)
        try:
            result = await self.behaviour.run(ctx)
        except asyncio.CancelledError:
            result = Outcome(False, "cancelled", None, self.behaviour.name)
            self._resolve(result)
            raise
        self._resolve(result)

    async def on_end(self) -> None:
        self._resolve(Outcome(False, "killed", None, self.behaviour.name))

    def _resolve(self, outcome: Outcome) -> None:
        if not self.outcome.done():
            self.outcome.set_result(outcome)
