"""Reactive strategies (agents/core_strategies.py): something that stands in the robot's path and then
goes away. The safety check stops the robot, the task pauses, "wait-for-clear" sees the way clear
again and hands back: the held path is driven to its own end and the task finishes."""
from __future__ import annotations

import asyncio

import pybullet as p
import pytest
import yaml

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
            core.strategies.wait_s = 20.0  # the test removes the obstacle while the strategy waits
            await wait_until(lambda: core.vocabulary and core.listening)

            def put_box():  # someone's box on the floor, 0.6 m ahead of the NAO (at x=1.0, facing +x)
                shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.15, 0.25, 0.4], physicsClientId=world.cid)
                return p.createMultiBody(0, shape, basePosition=[1.75, 2.4, 0.4], physicsClientId=world.cid)

            box = await world.run(put_box)
            task = asyncio.create_task(run_command(system, "pathecho", "path done", timeout=120))
            await wait_until(lambda: ("wait-for-clear", "start", None) in _strategy(system.settings.trace_file), 60)
            assert core.robot_commands.estop_reason and core.robot_commands.estop_by == "safety" and not task.done()
            await world.run(lambda: p.removeBody(box, physicsClientId=world.cid))  # taken away
            reply = await task
            assert "x=2.00" in reply  # the path's own end
            assert ("wait-for-clear", "end", "clear") in _strategy(system.settings.trace_file)
            assert ("back-off", "start", None) not in _strategy(system.settings.trace_file)
            await handle.user.wait_for(lambda t: "path-echo finished" in t, timeout=30)
    finally:
        world.close()


@pytest.mark.timeout(180)
async def test_the_plan_monitor_stops_a_late_plan_and_learns_where_the_way_is_blocked(tmp_path):
    """rapps/sdk/monitor.py with a real Core: a leg that cannot be done in time is stopped (arrive-by);
    a box that stays in the way makes the Core's strategies give up (blocked), and the obstacle event
    the Core sent just before tells the monitor where the box stands (path-free)."""
    world = World.from_file("small", seed=2, rtf=2.0)
    try:
        async with RappSystem(tmp_path, trace_file=tmp_path / "trace.jsonl") as system:
            await system.publish(variant(tmp_path, "late-echo", "lateecho", behaviour="monitored", within_s=1.5))
            await system.publish(variant(tmp_path, "boxed-echo", "boxedecho", behaviour="monitored"))
            handle = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")))
            system.handle, core = handle, handle.core
            core.strategies.wait_s = 0.5  # the box stays: no need to wait long for it to go
            await wait_until(lambda: core.vocabulary and core.listening)

            reply = await run_command(system, "lateecho", "plan failed", timeout=60)
            assert "arrive-by; obstacle nowhere" in reply
            assert 1.5 <= float(reply.split("after ")[1].split(" s")[0]) <= 2.5
            pose = world.ground_truth().robots["nao"]
            await asyncio.sleep(0.5)
            assert world.ground_truth().robots["nao"] == pose  # stopped, not walking on
            await handle.user.wait_for(lambda t: "late-echo finished" in t, timeout=30)
            await wait_until(lambda: core.listening)

            x0, y0, _ = world.ground_truth().robots["nao"]

            def put_box():  # a box that stays, its near face 0.55 m ahead of the NAO
                shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.15, 0.25, 0.4], physicsClientId=world.cid)
                return p.createMultiBody(0, shape, basePosition=[x0 + 0.7, y0, 0.4], physicsClientId=world.cid)

            await world.run(put_box)
            reply = await run_command(system, "boxedecho", "plan failed", timeout=90)
            assert "path-free; obstacle (" in reply
            ox, oy = (float(v) for v in reply.split("obstacle (")[1].split(")")[0].split(", "))
            # a sonar has no bearing: its echo is put on the cone's axis, so it lies on the box or near it
            dx, dy = max(x0 + 0.55 - ox, 0.0, ox - (x0 + 0.85)), max(y0 - 0.25 - oy, 0.0, oy - (y0 + 0.25))
            assert (dx * dx + dy * dy) ** 0.5 < 0.12, (ox, oy, x0, y0)
            assert world.person_contacts() == 0 and world.object_contacts() == 0
            steps = [s[0] for s in _strategy(system.settings.trace_file)]
            assert "back-off" in steps
            failed = [r for r in read_trace(system.settings.trace_file) if r["kind"] == "structure"
                      and r["event"] == "plan-failed"]
            assert [r["expectation"] for r in failed] == ["arrive-by", "path-free"]
    finally:
        world.close()


@pytest.mark.timeout(180)
async def test_a_wedged_motion_fails_blocked_and_a_paused_task_still_ends(tmp_path):
    """Issue 42: a robot wedged on something its range sensors do not see (a box below the NAO's
    sonars) reads clear the moment it stops; the Core resumes at most `max_resumes` times without
    progress, then backs off and fails the motion `blocked`, so the plan monitor learns the way is
    blocked. The owner hears one folded line, not a message per stop. And a task the owner stopped
    and forgot still ends: the time limit stops for paused time only up to an allowance."""
    low_box = {"disturbances": [{"kind": "box", "id": "toy", "at": 0.0, "position": [1.62, 2.4],
                                 "size": [0.3, 0.6, 0.12], "drop_height": 0.0}]}
    world = World.from_file("small", seed=2, rtf=2.0, disturbances=low_box)
    try:
        async with RappSystem(tmp_path, trace_file=tmp_path / "trace.jsonl") as system:
            await system.publish(variant(tmp_path, "boxed-echo", "boxedecho", behaviour="monitored"))
            idle = variant(tmp_path, "idle-echo", "idleecho", behaviour="silent")
            manifest = yaml.safe_load((idle / "manifest.yaml").read_text())
            limit = manifest["time_limit_s"] = 5.0
            (idle / "manifest.yaml").write_text(yaml.safe_dump(manifest))
            await system.publish(idle)
            handle = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao", pose=(1.0, 2.4, 0.0))))
            system.handle, core = handle, handle.core
            await wait_until(lambda: core.vocabulary and core.listening)

            reply = await run_command(system, "boxedecho", "plan failed", timeout=90)
            assert "path-free" in reply
            records = read_trace(system.settings.trace_file)
            estops = [r for r in records if r["kind"] == "structure" and r["event"] == "estop"]
            assert len(estops) == core.strategies.max_resumes + 1, [r["reason"] for r in estops]
            assert any("blocked the base" in r["reason"] for r in estops)
            steps = [s for s in _strategy(system.settings.trace_file) if s[1] == "start"]
            assert [s[0] for s in steps] == ["wait-for-clear"] * core.strategies.max_resumes + ["no-progress"]
            line = await handle.user.wait_for(lambda t: t.startswith("Safety: stopped"), timeout=30)
            assert f"stopped {core.strategies.max_resumes + 1} times" in line and "gave up on that way once" in line
            chat = handle.user.texts()
            assert not any(t.startswith(("Emergency stop", "Resumed")) for t in chat), chat
            await handle.user.wait_for(lambda t: "boxed-echo finished" in t, timeout=30)
            await wait_until(lambda: core.listening)

            core.strategies.pause_allowance_s = 2.0
            task = asyncio.create_task(run_command(system, "idleecho", "idle-echo ended", timeout=limit + 60))
            await wait_until(lambda: core.dynamic is not None and state(core) == "s8_serve", timeout=30)
            await handle.user.say(core.address, "stop")  # ... and never "resume"
            reply = await task
            assert f"time limit of {limit:g}s exceeded while waiting for your \"resume\"" in reply
            await handle.user.say(core.address, "resume")
    finally:
        world.close()


class _Host:
    """The Core's e-stop and strategy members on a robot that only records (no agents, no server)."""

    def __init__(self):
        self.robot_id, self.dynamic, self.told, self.records = "nao-1", None, [], []
        self.robot = type("R", (), {"halt": self.nothing, "handle": self.nothing})()

    def record_structure(self, event, **k):
        self.records.append((event, k))

    async def tell_user(self, text, speak=True, label=""):
        self.told.append(text)

    @staticmethod
    async def nothing(*a, **k):
        return None

    def in_background(self, coro):
        coro.close()


def _members():
    from agents.core_commands import RobotCommands
    from agents.core_strategies import Strategies

    host = _Host()
    commands = RobotCommands(host, publish=host.nothing)
    return host, commands, Strategies(host, commands, publish_echo=host.nothing)


async def test_an_owners_stop_during_a_safety_stop_is_the_owners_and_is_told():
    host, commands, strategies = _members()
    await commands.emergency_stop("obstacle ahead", by="safety")
    assert host.told == []  # a safety stop is told folded, when its incident is over
    await commands.emergency_stop("stopped by the user", by="owner")
    assert commands.estop_by == "owner" and host.told == ['Emergency stop: stopped by the user. Say "resume" to '
                                                          'let me move again.']
    assert not strategies._still_ours()  # the strategies let go: only the owner releases it
    assert strategies.waiting_for() == 'your "resume" (you stopped the robot)'
    await commands.resume_motion()
    assert host.told[-1] == "Resumed: I may move again."


def test_a_safety_incident_is_one_line():
    from agents.core_strategies import Incident

    i = Incident(4.31, 9.98, stops=12, done={"wait-for-clear": 3, "back-off": 8, "no-progress": 1})
    assert i.line("went on") == ("Safety: stopped 12 times for an obstacle ahead near (4.3, 10.0); waited for it "
                                 "to clear 3 times, backed off 8 times, gave up on that way once; went on.")
    assert Incident(1.0, 2.0, stops=1).line("the task ended") == \
        "Safety: stopped once for an obstacle ahead near (1.0, 2.0); the task ended."
