"""The behaviour formalism: terminal and error conditions, FSM with a sub-FSM, idle, hosting."""
from __future__ import annotations

import asyncio

import pytest

from behaviours import FSM, Behaviour, BehaviourHost, FSMError, Outcome
from behaviours.example import build as build_example


class Count(Behaviour):
    def __init__(self, name, limit, fail_at=None):
        super().__init__(name)
        self.limit, self.fail_at = limit, fail_at

    async def transition(self):
        self.memory[self.name] = self.memory.get(self.name, 0) + 1

    def terminal(self):
        return self.memory.get(self.name, 0) >= self.limit

    def error(self):
        if self.fail_at is not None and self.memory.get(self.name, 0) >= self.fail_at:
            return f"{self.name} hit {self.fail_at}"
        return None


async def test_terminal_condition_ends_behaviour():
    b = Count("c", 5)
    out = await b.run()
    assert out == Outcome(True, "", None, "c")
    assert b.iterations == 5 and b.memory["c"] == 5


async def test_error_condition_ends_with_reason():
    b = Count("c", 10, fail_at=3)
    out = await b.run()
    assert not out.ok and out.reason == "c hit 3"
    assert b.iterations == 3


async def test_exception_in_transition_is_an_error_and_timeout_is_enforced():
    class Boom(Behaviour):
        async def transition(self):
            raise ValueError("sensor unplugged")

    out = await Boom().run()
    assert out.error and out.reason == "ValueError: sensor unplugged"

    forever = Behaviour("forever", period=0.01, timeout=0.1)
    t0 = asyncio.get_running_loop().time()
    out = await forever.run()
    assert out.reason == "timeout after 0.1s"
    assert asyncio.get_running_loop().time() - t0 < 0.5


async def test_rate_is_respected():
    b = Count("slow", 3)
    b.period = 0.05
    t0 = asyncio.get_running_loop().time()
    await b.run()
    assert asyncio.get_running_loop().time() - t0 >= 0.14


async def test_fsm_with_sub_fsm_runs_expected_sequence():
    fsm = build_example(seed=1)
    out = await fsm.run()
    assert out.ok
    assert fsm.history == ["go_a", "measure", "go_b"]
    assert fsm.states["measure"].history == ["read", "pause", "read", "ok"]
    assert fsm.memory["pos"] == -2


async def test_sub_fsm_error_propagates_through_error_transition():
    inner = FSM("inner", initial="a")
    inner.add_state("a", Count("a", 5, fail_at=2))
    inner.add_state("b", Count("b", 1), final=True)
    inner.add_transition("a", "b")
    outer = FSM("outer", initial="inner")
    outer.add_state("inner", inner)
    outer.add_state("recover", Count("r", 1), final=True)
    outer.add_state("next", Count("n", 1), final=True)
    outer.add_transition("inner", "next")
    outer.add_transition("inner", "recover", on_error=True)
    out = await outer.run()
    assert out.ok and outer.history == ["inner", "recover"]
    assert outer.last_outcome.ok and inner.last_outcome.reason == "a hit 2"


async def test_unhandled_error_ends_fsm_with_state_and_reason():
    fsm = FSM("f", initial="a")
    fsm.add_state("a", Count("a", 5, fail_at=1))
    fsm.add_state("b", Count("b", 1), final=True)
    fsm.add_transition("a", "b")
    out = await fsm.run()
    assert not out.ok and out.reason == "a: a hit 1"


async def test_idle_runs_until_a_condition_holds():
    fsm = FSM("f", initial="a", idle_limit=2.0)
    fsm.add_state("a", Count("a", 1))
    fsm.add_state("b", Count("b", 1), final=True)
    fsm.add_transition("a", "b", when=lambda m, o: m.get("go"))

    async def later():
        await asyncio.sleep(0.2)
        fsm.memory["go"] = True

    setter = asyncio.create_task(later())
    out = await fsm.run()
    await setter
    assert out.ok and fsm.history == ["a", "b"]
    assert fsm.idle.iterations >= 1


async def test_no_applicable_transition_fails_at_once_naming_state_and_outcome():
    fsm = FSM("f", initial="a")
    fsm.add_state("a", Count("a", 1))
    fsm.add_state("b", Count("b", 1), final=True)
    fsm.add_transition("a", "b", when=lambda m, o: False)
    t0 = asyncio.get_running_loop().time()
    out = await fsm.run()
    assert asyncio.get_running_loop().time() - t0 < 0.5 and fsm.idle.iterations == 0
    assert not out.ok and "no transition applies from state 'a'" in out.reason and "(ok)" in out.reason


async def test_idle_limit_ends_fsm_when_nothing_applies():
    fsm = FSM("f", initial="a", idle_limit=0.15)
    fsm.add_state("a", Count("a", 1))
    fsm.add_state("b", Count("b", 1), final=True)
    fsm.add_transition("a", "b", when=lambda m, o: False)
    out = await fsm.run()
    assert not out.ok and "no transition applies" in out.reason


def test_invalid_fsm_is_refused():
    fsm = FSM("f", initial="a")
    fsm.add_state("a", Count("a", 1))
    fsm.add_transition("a", "zzz")
    with pytest.raises(FSMError, match="unknown state 'zzz'"):
        asyncio.run(fsm.run())


async def test_host_runs_behaviour_in_agent_and_traces_states(settings, unique, trace_file):
    from agents.base import RappAgent
    from agents.tracing import read_trace

    agent = RappAgent(unique("host"), settings)
    await agent.start()
    try:
        fsm = build_example(seed=1)
        host = BehaviourHost(fsm)
        agent.activate("patrol", host)
        out = await asyncio.wait_for(host.outcome, 5)
        assert out.ok
        states = [(r["fsm"], r["state"]) for r in read_trace(trace_file) if r["kind"] == "state"]
        assert states == [("patrol", "go_a"), ("patrol", "measure"), ("measure", "read"),
                          ("measure", "pause"), ("measure", "read"), ("measure", "ok"),
                          ("patrol", "go_b")]
    finally:
        await agent.stop()
