"""One request's pass through an FSM of its own (fig. 6's request FSM, fig. 5's s9): run side by side
with the other requests' passes, its states traced with the request's conversation."""
from __future__ import annotations

from dataclasses import dataclass, field

from behaviours import FSM
from behaviours.behaviour import Context


@dataclass
class TaggedContext(Context):
    """A context whose trace records carry the request they belong to."""

    tags: dict = field(default_factory=dict)

    def trace(self, kind: str, **fields) -> None:
        super().trace(kind, **{**fields, **self.tags})


async def run_pass(agent, fsm: FSM, memory: dict, conversation_id: str = ""):
    """Run one request's pass; memory["reply"] at its end, or the exception a step kept in
    memory["raised"] (a Refusal, a Failure, a typed error: the responder answers each as before)."""
    ctx = TaggedContext(agent=agent, memory=memory, tracer=getattr(agent, "tracer", None),
                        tags={"conversation_id": conversation_id} if conversation_id else {})
    outcome = await fsm.run(ctx)
    if "raised" in memory:
        raise memory.pop("raised")
    if not outcome.ok:
        raise RuntimeError(outcome.reason)
    return memory.get("reply")
