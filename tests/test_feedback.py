"""Actions with feedback and cancel (the ROS action pattern on FIPA request): request -> agree ->
progress informs -> inform; a cancel stops the action where it runs and ends it with
failure(cancelled). Over the real embedded server; then on a simulated robot's motion."""
from __future__ import annotations

import asyncio

import pytest

from agents.base import RappAgent
from agents.core_commands import path_progress
from agents.errors import RequestFailed
from agents.responder import Responder
from agents.tracing import read_trace
from ontology.errors import ErrorCode
from ontology.registry import Action, Done, Progress, action
from ontology.robot import MoveAlongPath
from ontology.services.common import Pose2D
from robots import RobotAPI, World


@action("count_slowly", ontology="test-feedback", reply=Done)
class CountSlowly(Action):
    steps: int


async def start_pair(settings, unique):
    state = {"cancelled": False, "steps": 0}

    async def count(req, ctx):
        try:
            for i in range(req.steps):
                await asyncio.sleep(0.05)
                state["steps"] = i + 1
                await ctx.feedback(Progress(fraction=(i + 1) / req.steps, text=f"step {i + 1}"))
        except asyncio.CancelledError:
            state["cancelled"] = True
            raise
        return Done()

    server, client = RappAgent(unique("worker"), settings), RappAgent(unique("boss"), settings)
    await server.start()
    await client.start()
    responder = Responder("test-feedback", {"count_slowly": count})
    server.activate("work", responder, responder.make_template())
    return server, client, state


async def test_progress_informs_then_the_final_answer(settings, unique):
    server, client, state = await start_pair(settings, unique)
    try:
        seen: list[Progress] = []
        reply = await client.request(server.address, CountSlowly(steps=4), timeout=10, on_feedback=seen.append)
        assert reply == Done() and [p.fraction for p in seen] == [0.25, 0.5, 0.75, 1.0]
        quiet = await client.request(server.address, CountSlowly(steps=2), timeout=10)  # no feedback asked
        assert quiet == Done()
        records = [r for r in read_trace(settings.trace_file) if r["kind"] == "message" and r["dir"] == "recv"
                   and r["agent"] == client.address]
        performatives = [(r["performative"], bool(r.get("feedback"))) for r in records]
        assert performatives == [("agree", False)] + [("inform", True)] * 4 + [("inform", False)] * 2
    finally:
        await client.stop()
        await server.stop()


async def test_cancelling_the_caller_cancels_the_action(settings, unique):
    server, client, state = await start_pair(settings, unique)
    try:
        seen: list[Progress] = []
        call = asyncio.create_task(client.request(server.address, CountSlowly(steps=200), timeout=30,
                                                  on_feedback=seen.append))
        while len(seen) < 2:
            await asyncio.sleep(0.02)
        call.cancel()
        with pytest.raises(asyncio.CancelledError):
            await call
        for _ in range(100):
            if state["cancelled"]:
                break
            await asyncio.sleep(0.02)
        assert state["cancelled"] and state["steps"] < 50  # stopped where it ran, long before the end
        failures = [r for r in read_trace(settings.trace_file) if r["kind"] == "message"
                    and r["performative"] == "failure" and r["agent"] == server.address]
        assert failures and '"cancelled"' in failures[-1]["content"]
    finally:
        await client.stop()
        await server.stop()


def test_path_progress_is_the_length_behind_the_nearest_point():
    path = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0)]
    assert path_progress(path, 0.0, 0.0) == 0.0
    assert path_progress(path, 1.0, 0.1) == pytest.approx(0.25)
    assert path_progress(path, 2.1, 1.0) == pytest.approx(0.75)
    assert path_progress(path, 5.0, 5.0) == 1.0


async def test_a_cancelled_motion_stops_the_robot():
    world = World.from_file("small", seed=1)
    try:
        api = RobotAPI(world.add_robot("elektron"))
        x, y, _ = api.robot.pose
        path = [Pose2D(x=x + 0.5 * i, y=y, theta=0.0) for i in range(6)]
        motion = asyncio.create_task(api.handle(MoveAlongPath(poses=path)))
        await world.sleep(1.0)
        motion.cancel()
        with pytest.raises(asyncio.CancelledError):
            await motion
        stopped = api.robot.pose
        await world.sleep(1.0)
        assert api.robot.pose[:2] == pytest.approx(stopped[:2], abs=0.01)  # nothing drives it any more
        assert abs(stopped[0] - x) < 2.4  # it did not finish the 2.5 m path
        assert "base" not in api.robot.controllers
    finally:
        world.close()


async def test_failure_of_a_cancelled_request_has_the_cancelled_code(settings, unique):
    """A responder whose handler is cancelled (its agent stopping) answers failure(cancelled)."""
    server, client, _ = await start_pair(settings, unique)
    try:
        call = asyncio.create_task(client.request(server.address, CountSlowly(steps=400), timeout=30))
        await asyncio.sleep(0.3)
        for task in list(server.behaviours):
            if isinstance(task, Responder):
                for t in list(task._running.values()):
                    t.cancel()
        with pytest.raises(RequestFailed) as e:
            await call
        assert e.value.code == ErrorCode.CANCELLED
    finally:
        await client.stop()
        await server.stop()


async def test_halt_stops_head_and_base_and_silences_the_loudspeaker():
    """The emergency stop's robot side: every running motion is interrupted, speech is cut off."""
    import numpy as np

    from ontology.robot import LookAtPoint
    from robots.errors import MotionInterrupted
    from robots.sound import house_sound

    world = World.from_file("small", seed=1)
    try:
        api = RobotAPI(world.add_robot("nao"))
        x, y, _ = api.robot.pose
        walk = asyncio.create_task(api.handle(MoveAlongPath(poses=[Pose2D(x=x + 0.5 * i, y=y, theta=0.0)
                                                                   for i in range(6)])))
        look = asyncio.create_task(api.handle(LookAtPoint(x=x - 3.0, y=y + 3.0, z=0.0)))
        api.robot.loudspeaker.play(np.full(16000 * 5, 3000, np.int16), world.time, text="a long sentence")
        await world.sleep(0.3)
        await api.halt("emergency stop")
        for motion in (walk, look):
            with pytest.raises(MotionInterrupted, match="stopped by emergency stop"):
                await motion
        assert api.robot.controllers == {}
        assert not any(s.startswith("loudspeaker:") for s in house_sound(world).sources)
    finally:
        world.close()
