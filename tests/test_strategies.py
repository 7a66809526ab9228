"""Reactive strategies (agents/core_strategies.py): something that stands in the robot's path and then
goes away. The safety check stops the robot, the task pauses, "wait-for-clear" sees the way clear
again and hands back: the held path is driven to its own end and the task finishes."""
from __future__ import annotations

import asyncio

import pybullet as p
import pytest

from agents.tracing import read_trace
from robots import RobotAPI, World
from scenarios.system import RappSystem

from .test_lifecycle import run_command, state, variant, wait_until


def _strategy(trace_file) -> list[tuple]:
    return [(r["strategy"], r["phase"], r.get("outcome")) for r in read_trace(trace_file)
            if r["kind"] == "structure" and r["event"] == "strategy"]


@pytest.mark.timeout(180)
async def test_wait_for_clear_hands_the_path_back(tmp_path):
    world = World.from_file("small", seed=2, rtf=2.0)
    try:
        async with RappSystem(tmp_path, trace_file=tmp_path / "trace.jsonl") as system:
            await system.publish(variant(tmp_path, "path-echo", "pathecho", behaviour="path", distance=1.0))
            handle = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")))
            system.handle, core = handle, handle.core
            core.wait_s = 20.0  # the test removes the obstacle while the strategy waits
            await wait_until(lambda: core.vocabulary and state(core) == "s3_listen")

            def put_box():  # someone's box on the floor, 0.6 m ahead of the NAO (at x=1.0, facing +x)
                shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.15, 0.25, 0.4], physicsClientId=world.cid)
                return p.createMultiBody(0, shape, basePosition=[1.75, 2.4, 0.4], physicsClientId=world.cid)

            box = await world.run(put_box)
            task = asyncio.create_task(run_command(system, "pathecho", "path done", timeout=120))
            await wait_until(lambda: ("wait-for-clear", "start", None) in _strategy(system.settings.trace_file), 60)
            assert core.estop_reason and core.estop_by == "safety" and not task.done()
            await world.run(lambda: p.removeBody(box, physicsClientId=world.cid))  # taken away
            reply = await task
            assert "x=2.00" in reply  # the path's own end
            assert ("wait-for-clear", "end", "clear") in _strategy(system.settings.trace_file)
            assert ("back-off", "start", None) not in _strategy(system.settings.trace_file)
            await handle.user.wait_for(lambda t: "path-echo finished" in t, timeout=30)
    finally:
        world.close()
