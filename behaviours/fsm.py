"""An FSM whose states are behaviours; a state may itself be an FSM (a sub-FSM, the double-circled
nodes of figs 5 and 16 of paper 000).

    fsm = FSM("hazard", initial="s1")
    fsm.add_state("s1", GetMap())
    fsm.add_state("s2", localize_fsm)                      # sub-FSM
    fsm.add_transition("s1", "s2")                         # taken when s1 ends ok
    fsm.add_transition("s2", "s2_retry", on_error=True)    # taken when s2 ends with an error
    fsm.add_transition("s3", "s5", when=lambda m, o: m["path"])   # condition over memory/outcome
    fsm.add_final("s7")

After a state's behaviour ends, the transitions leaving it are tried in the order added; the first
whose condition holds is taken. If none holds, the FSM ends at once with an error naming the state
and its outcome; with `idle_limit` (seconds, None = forever) it first runs its idle behaviour and
tries again until the limit (paper 002: the idle behaviour applies when nothing else does; the
Core's FSM waits so). A final state ends the FSM with that state's outcome; an error outcome
with no error transition ends the FSM with that error. The FSM is a Behaviour, so it nests.
"""
from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Any, Callable

from .behaviour import Behaviour, Context, Idle, Outcome

Condition = Callable[[dict[str, Any], Outcome], bool]


@dataclass
class Transition:
    source: str
    target: str
    when: Condition | None
    on_error: bool


class FSMError(Exception):
    pass


def describe(outcome: Outcome) -> str:
    """An outcome in a few words, for the reason of a failure."""
    text = "ok" if outcome.ok else f"error: {outcome.reason}"
    return text if outcome.value is None else f"{text}; value {str(outcome.value)[:80]!r}"


class FSM(Behaviour):
    def __init__(self, name: str, initial: str, *, idle: Behaviour | None = None,
                 idle_limit: float | None = 0.0, max_steps: int = 100_000):
        super().__init__(name)
        self.initial = initial
        self.states: dict[str, Behaviour] = {}
        self.transitions: list[Transition] = []
        self.finals: set[str] = set()
        self.idle = idle or Idle("idle")
        self.idle_limit = idle_limit
        self.max_steps = max_steps
        self.current: str | None = None
        self.history: list[str] = []  # states entered, in order (sub-FSMs keep their own)
        self.last_outcome: Outcome | None = None

    # -- building ---------------------------------------------------------------------------
    def add_state(self, name: str, behaviour: Behaviour, *, final: bool = False) -> "FSM":
        if name in self.states:
            raise FSMError(f"state {name!r} already in FSM {self.name!r}")
        self.states[name] = behaviour
        if final:
            self.finals.add(name)
        return self

    def add_final(self, name: str) -> "FSM":
        self.finals.add(name)
        return self

    def add_transition(self, source: str, target: str, *, when: Condition | None = None,
                       on_error: bool = False) -> "FSM":
        self.transitions.append(Transition(source, target, when, on_error))
        return self

    def validate(self) -> None:
        names = set(self.states)
        if self.initial not in names:
            raise FSMError(f"FSM {self.name!r}: initial state {self.initial!r} has no behaviour")
        for t in self.transitions:
            for end in (t.source, t.target):
                if end not in names:
                    raise FSMError(f"FSM {self.name!r}: transition {t.source}->{t.target} names unknown state {end!r}")
        for f in self.finals:
            if f not in names:
                raise FSMError(f"FSM {self.name!r}: final state {f!r} has no behaviour")

    # -- running ----------------------------------------------------------------------------
    async def run(self, ctx: Context | None = None) -> Outcome:
        self.validate()
        return await super().run(ctx)

    async def _loop(self) -> Outcome:
        self.history = []
        state = self.initial
        for _ in range(self.max_steps):
            await self.ctx.hold()  # paused: the next state waits for the resume
            self.current = state
            self.history.append(state)
            self.ctx.trace("state", event="enter", fsm=self.name, state=state)
            behaviour = self.states[state]
            outcome = await behaviour.run(self.ctx)
            self.last_outcome = outcome
            if state in self.finals:
                return Outcome(outcome.ok, outcome.reason, outcome.value, self.name)
            nxt = await self._next(state, outcome)
            if nxt is None:
                if outcome.error:
                    return Outcome(False, f"{state}: {outcome.reason}", outcome.value, self.name)
                return Outcome(False, f"FSM {self.name!r}: no transition applies from state {state!r} after "
                                      f"its outcome ({describe(outcome)})", outcome.value, self.name)
            state = nxt
        return Outcome(False, f"more than {self.max_steps} steps", None, self.name)

    def _choose(self, state: str, outcome: Outcome) -> str | None:
        for t in self.transitions:
            if t.source != state or t.on_error != outcome.error:
                continue
            if t.when is None or t.when(self.memory, outcome):
                return t.target
        return None

    async def _next(self, state: str, outcome: Outcome) -> str | None:
        nxt = self._choose(state, outcome)
        if nxt is not None or not self.idle_limit or not self._has_conditional(state, outcome):
            return nxt
        loop = asyncio.get_running_loop()
        deadline = None if self.idle_limit is None else loop.time() + self.idle_limit
        while nxt is None:
            if deadline is not None and loop.time() > deadline:
                return None
            await self.idle.run(self.ctx)
            nxt = self._choose(state, outcome)
        return nxt

    def _has_conditional(self, state: str, outcome: Outcome) -> bool:
        return any(t.source == state and t.on_error == outcome.error and t.when is not None
                   for t in self.transitions)
