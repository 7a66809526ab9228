"""Behaviour-tree composites and decorators on paper 002's contract, nested with FSMs."""
from __future__ import annotations

import asyncio

import pytest

from behaviours import FSM, Behaviour, Inverter, OneShot, Parallel, Retry, Selector, Sequence, Timeout


class Do(OneShot):
    """Appends its name to memory["log"]; fails when told to (or for its first `fail_times` runs)."""

    def __init__(self, name, fail=False, fail_times=0, delay=0.0, value=None):
        super().__init__(name)
        self.fail, self.fail_times, self.delay, self.value, self.runs = fail, fail_times, delay, value, 0

    async def action(self):
        self.runs += 1
        await asyncio.sleep(self.delay)
        self.memory.setdefault("log", []).append(self.name)
        if self.fail or self.runs <= self.fail_times:
            raise RuntimeError(f"{self.name} failed")
        return self.value


async def test_sequence_runs_in_order_and_stops_at_the_first_error():
    seq = Sequence("s", [Do("a"), Do("b", fail=True), Do("c")])
    out = await seq.run()
    assert not out.ok and out.reason == "b: RuntimeError: b failed"
    assert seq.memory["log"] == ["a", "b"]
    ok = Sequence("s", [Do("a"), Do("b", value=7)])
    assert (await ok.run()).ok and ok.memory["log"] == ["a", "b"] and ok.current == "b"


async def test_selector_falls_back_until_one_succeeds():
    sel = Selector("sel", [Do("a", fail=True), Do("b", value=2), Do("c")])
    out = await sel.run()
    assert out.ok and out.value == 2 and sel.memory["log"] == ["a", "b"]
    none = await Selector("sel", [Do("a", fail=True), Do("b", fail=True)]).run()
    assert not none.ok and "a: RuntimeError" in none.reason and "b: RuntimeError" in none.reason


async def test_parallel_all_and_one_policies_cancel_the_rest():
    slow = Do("slow", delay=5.0)
    out = await Parallel("p", [Do("quick", fail=True, delay=0.01), slow], policy="all").run()
    assert not out.ok and out.reason.startswith("quick:") and slow.runs == 1  # started, then cancelled
    both = await Parallel("p", [Do("a", value=1), Do("b", value=2)]).run()
    assert both.ok and both.value == {"a": 1, "b": 2}
    t0 = asyncio.get_running_loop().time()
    first = await Parallel("p", [Do("fast", value="f", delay=0.01), Do("slow", delay=5.0)], policy="one").run()
    assert first.ok and first.value == "f" and asyncio.get_running_loop().time() - t0 < 1.0
    with pytest.raises(ValueError):
        Parallel("p", [Do("a")], policy="most")


async def test_decorators_timeout_retry_inverter():
    out = await Timeout(Do("slow", delay=5.0), 0.05).run()
    assert not out.ok and "timeout after 0.05s" in out.reason
    flaky = Do("flaky", fail_times=2, value="ok")
    assert (await Retry(flaky, attempts=3).run()).value == "ok" and flaky.runs == 3
    hopeless = Do("h", fail=True)
    out = await Retry(hopeless, attempts=2).run()
    assert not out.ok and "failed 2 times" in out.reason and hopeless.runs == 2
    assert (await Inverter(Do("x", fail=True)).run()).ok
    assert not (await Inverter(Do("x")).run()).ok


async def test_trees_in_fsm_states_and_fsms_in_trees_share_memory():
    inner = FSM("inner", initial="i1")
    inner.add_state("i1", Do("i1"))
    inner.add_state("i2", Do("i2"), final=True)
    inner.add_transition("i1", "i2")
    fsm = FSM("outer", initial="tree")
    fsm.add_state("tree", Sequence("seq", [Do("a"), inner, Selector("sel", [Do("x", fail=True), Do("y")])]))
    fsm.add_state("end", Do("end"), final=True)
    fsm.add_transition("tree", "end")
    out = await fsm.run()
    assert out.ok and fsm.memory["log"] == ["a", "i1", "i2", "x", "y", "end"]


def test_empty_composites_and_bad_retry_are_refused():
    with pytest.raises(ValueError):
        Sequence("s", [])
    with pytest.raises(ValueError):
        Retry(Behaviour("b"), attempts=0)
