"""Resource locks with inheritance, as paper 003 sec. V-B defines them: a device is locked by one
program at a time, and its usage authorization can be inherited (handed down to a program acting
for the holder, and back). The Core's back-off strategy acts for the task this way."""
from __future__ import annotations

import asyncio

import pytest

from agents.core_strategies import Strategies
from agents.locks import LockError, ResourceLocks
from ontology.registry import Done
from ontology.robot import GetGlobalPose
from ontology.services.common import Pose2D


async def test_an_heir_uses_the_device_and_the_owner_gets_it_back():
    locks = ResourceLocks()
    assert locks.try_lock("base", "fp")
    locks.lend("base", "fp", "block")
    assert locks.holder("base") == "block" and locks.owner("base") == "fp"
    assert locks.chain("base") == ("fp", "block")
    # one user at a time: the owner too waits while its heir acts
    assert not locks.try_lock("base", "fp") and not locks.try_lock("base", "other")
    assert locks.try_lock("base", "block")  # re-entrant for the heir
    locks.free("base", "block")
    assert locks.give_back("base", "block") == "fp"
    assert locks.holder("base") == "fp" and locks.try_lock("base", "fp")
    locks.free("base", "fp")
    locks.free("base", "fp")
    assert locks.holder("base") is None


async def test_inheritance_chains_and_the_last_free_returns_it():
    locks = ResourceLocks()
    assert locks.try_lock("camera", "a")
    locks.lend("camera", "a", "b")
    locks.lend("camera", "b", "c")  # an heir lends on (a block within a block)
    assert locks.chain("camera") == ("a", "b", "c")
    with pytest.raises(LockError, match="already holds"):
        locks.lend("camera", "c", "a")  # no cycle
    with pytest.raises(LockError, match="cannot lend"):
        locks.lend("camera", "a", "d")  # only the one using it may hand it down
    locks.free("camera", "c")  # its inherited hold was its only one: back to b
    assert locks.holder("camera") == "b"
    with pytest.raises(LockError, match="not inherited"):
        locks.give_back("camera", "a")


async def test_an_ended_owner_takes_what_it_lent_along_and_an_ended_heir_returns_it():
    locks = ResourceLocks()
    assert locks.try_lock("base", "dyn") and locks.try_lock("head", "dyn")
    locks.lend("base", "dyn", "core:back-off")
    locks.lend("base", "core:back-off", "deeper")
    assert locks.free_all("core:back-off") == []  # nothing owned: the base goes back to dyn
    assert locks.chain("base") == ("dyn",)
    locks.lend("base", "dyn", "core:back-off")
    assert sorted(locks.free_all("dyn")) == ["base", "head"]
    assert locks.holder("base") is None and locks.holder("head") is None


async def test_a_waiter_gets_the_device_only_when_the_whole_chain_is_done():
    locks = ResourceLocks()
    assert locks.try_lock("base", "fp")
    locks.lend("base", "fp", "block")
    owner_back = asyncio.create_task(locks.lock("base", "fp", timeout=2))  # the owner waits for its heir
    stranger = asyncio.create_task(locks.lock("base", "other", timeout=2))
    await asyncio.sleep(0.02)
    assert not owner_back.done() and not stranger.done()
    locks.give_back("base", "block")
    assert await owner_back and locks.holder("base") == "fp"
    await asyncio.sleep(0.02)
    assert not stranger.done()  # held twice by fp now
    locks.free("base", "fp")
    locks.free("base", "fp")
    assert await stranger and locks.chain("base") == ("other",)


async def test_acting_for_inherits_from_the_user_or_locks_a_free_device():
    locks = ResourceLocks()
    async with locks.acting_for("base", "core:back-off") as giver:
        assert giver is None and locks.chain("base") == ("core:back-off",)
    assert locks.holder("base") is None
    assert locks.try_lock("base", "dyn")
    async with locks.acting_for("base", "core:back-off") as giver:
        assert giver == "dyn" and locks.holder("base") == "core:back-off"
    assert locks.chain("base") == ("dyn",)
    async with locks.acting_for("base", "core:back-off"):
        locks.free_all("dyn")  # the task ended meanwhile: nothing to give back to
    assert locks.holder("base") is None


class _Robot:
    """Records who may use the base while the strategy's motion runs."""

    def __init__(self, locks):
        self.locks, self.moves = locks, []

    async def handle(self, req):
        if isinstance(req, GetGlobalPose):  # where the safety incident is
            return Pose2D(x=0.0, y=0.0, theta=0.0)
        self.moves.append((type(req).__name__, self.locks.chain("base")))
        return Done()


class _Core:
    """The strategies' host and safety latch (agents/core_parts.py StrategiesHost, SafetyLatch)."""

    safety_distance = 0.3

    def __init__(self):
        self.locks = ResourceLocks()
        self.robot = _Robot(self.locks)
        self.estop_reason, self.estop_by, self.fail_held = "obstacle ahead", "safety", None
        self.records, self.resumed = [], []
        self.dynamic = None  # a task-less Core: the incident is told when it closes

    def record_structure(self, event, **fields):
        self.records.append((event, fields))

    async def nearest_obstacle(self):
        return 0.05  # a wall stays ahead

    async def nearest_echo(self):
        return None

    async def resume_motion(self, by):
        self.resumed.append(by)
        self.estop_reason = None

    def in_background(self, coro) -> None:
        coro.close()

    async def tell_user(self, text, speak=True):
        self.records.append(("told", {"text": text}))


async def test_the_back_off_acts_for_the_task_with_its_inherited_base():
    core = _Core()
    strategies = Strategies(core, core, publish_echo=None)  # no echo to publish: nearest_echo reads none
    strategies.wait_s = 0.05
    assert core.locks.try_lock("base", "dyn-1")  # the task's held motion keeps the base
    assert await strategies.react_to_obstacle() == "back-off"
    assert core.robot.moves == [("MoveTo", ("dyn-1", "core:back-off"))]
    assert core.locks.chain("base") == ("dyn-1",)  # given back to the task
    end = [f for e, f in core.records if e == "strategy" and f["strategy"] == "back-off" and f["phase"] == "end"]
    assert end[-1]["base_given_back_to"] == "dyn-1" and core.resumed == ["strategy:back-off"]
