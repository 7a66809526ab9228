"""Rights: manifest permissions (robot-API groups, Platform services), emergency stop and resume,
the safety distance, resource locks, and package signatures checked by the Core."""
from __future__ import annotations

import asyncio

import pytest
import yaml

from agents.locks import LockError, ResourceLocks
from agents.messages import bare
from agents.tracing import read_trace
from ontology.package import build_package_bytes, generate_keypair
from robots import RobotAPI, World
from scenarios.system import RappSystem

from .test_lifecycle import FIXTURE, SUPERVISING, run_command, variant, wait_until


def edit_manifest(src, **changes):
    path = src / "manifest.yaml"
    m = yaml.safe_load(path.read_text())
    m.update(changes)
    path.write_text(yaml.safe_dump(m))
    return src


@pytest.fixture(scope="module")
async def system(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("rights")
    world = World.from_file("small", seed=2, rtf=4.0)  # motions take (a little) time: stops can land
    async with RappSystem(workdir, trace_file=workdir / "trace.jsonl") as system:
        await system.publish(FIXTURE)
        await system.publish(edit_manifest(variant(workdir, "mute-echo", "muteecho"), robot_api=["communication"]))
        await system.publish(variant(workdir, "greedy-echo", "greedyecho", call_service="path_planning_list_maps"))
        await system.publish(variant(workdir, "drive-echo", "driveecho", behaviour="drive", distance=6.0))
        await system.publish(variant(workdir, "lock-echo", "lockecho", lock="camera"))
        await system.publish(variant(workdir, "cruise-echo", "cruiseecho", behaviour="cruise"))
        await system.publish(variant(workdir, "path-echo", "pathecho", behaviour="path", distance=1.0))
        await system.publish(variant(workdir, "release-echo", "releaseecho", behaviour="release"))
        await system.publish(variant(workdir, "events-echo", "eventsecho", behaviour="events"))
        system.world = world
        system.handle = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")))
        await wait_until(lambda: system.handle.core.vocabulary and system.handle.core.listening)
        yield system
    world.close()


async def test_undeclared_robot_group_is_refused(system):
    reply = await run_command(system, "muteecho", "mute-echo ended with a problem")
    assert "did not declare the robot-API group 'navigation'" in reply


async def test_undeclared_service_is_refused(system):
    reply = await run_command(system, "greedyecho", "greedy-echo ended with a problem")
    assert "did not declare the service 'path_planning_list_maps'" in reply


def _events(system, event: str) -> list[dict]:
    return [r for r in read_trace(system.settings.trace_file) if r["kind"] == "structure" and r["event"] == event]


async def test_user_stop_pauses_the_task_and_resume_finishes_it(system):
    """Paper 003: "stop" halts every effector and pauses the task (its path is held, not failed);
    "resume" lets the same path finish where it was meant to end."""
    core, world = system.handle.core, system.world
    x0 = world.ground_truth().robots["nao"][0]
    goal = x0 + (1.0 if x0 < 1.75 else -1.0)  # the echo RApp's path: 1 m towards the room's middle
    task = asyncio.create_task(run_command(system, "pathecho", "path done", timeout=90))
    await wait_until(lambda: abs(world.ground_truth().robots["nao"][0] - x0) > 0.2, timeout=30)  # on its way
    await run_command(system, "stop", "Emergency stop: stopped by the user")
    pose = world.ground_truth().robots["nao"]
    await asyncio.sleep(1.0)
    assert world.ground_truth().robots["nao"] == pose  # nothing moves
    assert core.dynamic is not None and not core.dynamic.ended.is_set()  # paused, not ended
    assert not task.done()
    await wait_until(lambda: _events(system, "task-paused") and _events(system, "motion-held"), timeout=10)
    await run_command(system, "resume", "I may move again")
    reply = await task
    assert "paused now: None" in reply
    x_end = float(reply.split("x=")[1].split(",")[0])
    assert abs(x_end - goal) < 0.1  # the path's own end, not an offset from where it stopped
    await system.handle.user.wait_for(lambda t: "path-echo finished" in t, timeout=30)
    assert _events(system, "task-resumed") and _events(system, "motion-resumed")
    await wait_until(lambda: core.active_behaviours() == SUPERVISING)


async def test_cancel_ends_the_task_without_latching(system):
    core = system.handle.core
    task = asyncio.create_task(run_command(system, "driveecho", "drive-echo ended with a problem"))
    await wait_until(lambda: "command-server" in core.active_behaviours())
    await asyncio.sleep(0.5)  # driving now
    await system.handle.user.say(core.address, "cancel")
    reply = await task
    assert "cancelled by the user" in reply
    assert core.robot_commands.estop_reason is None
    await wait_until(lambda: core.active_behaviours() == SUPERVISING)


async def test_stop_while_idle_holds_the_next_task_until_resume(system):
    core = system.handle.core
    await run_command(system, "stop", "Emergency stop")
    task = asyncio.create_task(run_command(system, "pathecho", "path done", timeout=90))
    held = len(_events(system, "motion-held"))
    await wait_until(lambda: len(_events(system, "motion-held")) > held, timeout=30)
    # the task cannot release an owner's stop
    assert not task.done()
    await run_command(system, "resume", "I may move again")
    await task
    await system.handle.user.wait_for(lambda t: "path-echo finished" in t, timeout=30)
    assert core.robot_commands.estop_reason is None
    await wait_until(lambda: core.active_behaviours() == SUPERVISING)


async def test_obstacle_within_safety_distance_latches_estop_and_strategies_hand_back(system):
    """Paper 004's reactive strategies: a wall ahead stays, so waiting does not clear it; the Core backs
    off and hands the robot back (the interrupted relative move has already failed: code estop)."""
    core = system.handle.core
    start = len(system.handle.user.received)
    await run_command(system, "driveecho", "drive-echo ended", timeout=60)
    assert any("obstacle" in r["reason"] and r["by"] == "safety" for r in _events(system, "estop"))
    await wait_until(lambda: core.robot_commands.estop_reason is None, timeout=30)  # released by the strategy
    # a safety stop is one folded line to the owner, not "Emergency stop ... say resume"
    line = await system.handle.user.wait_for(lambda t: t.startswith("Safety: stopped once"), timeout=30, start=start)
    assert "backed off once" in line and "the task ended" in line
    assert not any(t.startswith("Emergency stop") for t in system.handle.user.texts()[start:])
    steps = [(r["strategy"], r["phase"], r.get("outcome")) for r in _events(system, "strategy")]
    assert steps[-4:] == [("wait-for-clear", "start", None), ("wait-for-clear", "end", "still blocked"),
                          ("back-off", "start", None), ("back-off", "end", "backed off")]
    assert _events(system, "estop-released")[-1]["by"] == "strategy:back-off"
    # the relative move had failed and freed the base: the back-off locks it itself (tests/test_locks.py:
    # a task still holding it lends it)
    assert _events(system, "strategy")[-2]["base"] == ["core:back-off"]
    await wait_until(lambda: core.active_behaviours() == SUPERVISING)


async def test_the_task_may_release_a_safety_stop_but_not_the_owners(system):
    core = system.handle.core
    await core.robot_commands.emergency_stop("bumper pressed", by="safety")  # a stop no strategy handles
    await run_command(system, "releaseecho", "stop released")
    assert core.robot_commands.estop_reason is None
    await system.handle.user.wait_for(lambda t: "release-echo finished" in t, timeout=30)
    await wait_until(lambda: core.active_behaviours() == SUPERVISING)
    await run_command(system, "stop", "Emergency stop")
    await run_command(system, "releaseecho", "release refused: permission")
    assert core.robot_commands.estop_reason == "stopped by the user"
    await wait_until(lambda: core.active_behaviours() == SUPERVISING)
    await run_command(system, "resume", "I may move again")


async def test_a_task_subscribes_to_estop_events_and_expired_ones_are_dropped(system):
    """Paper 003's typed notifications: FIPA subscribe to the Core's events; each carries kind, stamp
    and expiry; one that arrives expired is dropped and traced, never handed to the task."""
    from ontology.notifications import EventTopic, Notification

    core = system.handle.core
    task = asyncio.create_task(run_command(system, "eventsecho", "events-echo finished", timeout=60))
    await system.handle.user.wait_for(lambda t: t == "[events-echo] subscribed", timeout=30)  # its words, labelled
    dyn = core.dynamic.jid
    await core.events.send_notification(Notification.event(EventTopic.ESTOP, ttl_s=-1.0, latched=True), [bare(dyn)])
    await wait_until(lambda: any(r.get("topic") == "estop" for r in _events(system, "notification-expired")))
    await run_command(system, "stop", "event event estop latched=True fresh=True")
    await run_command(system, "resume", "event event estop latched=False fresh=True")
    await task
    assert not core.events.subscriptions  # they end with the task


async def test_velocity_driving_is_watched_by_the_safety_monitor(system):
    core = system.handle.core
    stops = len(_events(system, "estop"))
    await run_command(system, "cruiseecho", "Starting cruise-echo", timeout=60)
    await wait_until(lambda: any(r["by"] == "safety" for r in _events(system, "estop")[stops:]), timeout=60)
    pose = system.world.ground_truth().robots["nao"]
    await asyncio.sleep(0.3)
    assert system.world.ground_truth().robots["nao"] == pose  # halted while the strategy waits
    await wait_until(lambda: core.robot_commands.estop_reason is None, timeout=30)  # backed off and handed back
    pose = system.world.ground_truth().robots["nao"]
    await asyncio.sleep(0.3)
    assert system.world.ground_truth().robots["nao"] == pose  # a velocity is not restored
    await run_command(system, "cancel", "cruise-echo ended with a problem")
    await wait_until(lambda: core.active_behaviours() == SUPERVISING)


async def test_resource_lock_held_by_core_behaviour_is_refused_to_rapp(system):
    core = system.handle.core
    assert core.robot_commands.locks.try_lock("camera", "core:calibration")
    try:
        await run_command(system, "lockecho", "lock camera: held=False holder=core:calibration")
        await system.handle.user.wait_for(lambda t: "lock-echo finished" in t, timeout=30)
    finally:
        core.robot_commands.locks.free("camera", "core:calibration")
    await run_command(system, "lockecho", "lock camera: held=True holder=dyn-")


async def test_lock_semantics():
    locks = ResourceLocks()
    assert locks.try_lock("base", "a") and locks.try_lock("base", "a")  # re-entrant
    assert not locks.try_lock("base", "b")
    assert not await locks.lock("base", "b", timeout=0.05)
    waiter = asyncio.create_task(locks.lock("base", "b", timeout=2))
    locks.free("base", "a")
    await asyncio.sleep(0.01)
    assert not waiter.done()  # still held once by a
    locks.free("base", "a")
    assert await waiter and locks.holder("base") == "b"
    with pytest.raises(LockError, match="held by b, not by a"):
        locks.free("base", "a")
    with pytest.raises(LockError, match="unknown resource"):
        locks.try_lock("wings", "a")


async def test_core_verifies_signatures(tmp_path):
    key, pub = generate_keypair()
    _, other_pub = generate_keypair()
    signed = tmp_path / "signed-echo"
    variant(tmp_path, "signed-echo", "signedecho")
    unsigned = variant(tmp_path, "unsigned-echo", "unsignedecho")
    world = World.from_file("small", seed=4)
    async with RappSystem(tmp_path / "run") as system:
        from agents.store_client import publish_package
        from ontology.store import RegisterOwner
        await system.publisher.request(system.store.address, RegisterOwner(owner="dev", password="pw"))
        await publish_package(system.publisher, system.store.address, "dev", "pw",
                              build_package_bytes(signed, signing_key=key))
        await publish_package(system.publisher, system.store.address, "dev", "pw",
                              build_package_bytes(unsigned))  # system.publish would sign it
        trusting = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")),
                                          trusted_keys=[pub], require_signature=True)
        doubting = await system.add_robot("elektron", api=RobotAPI(world.add_robot("elektron")),
                                          trusted_keys=[other_pub], require_signature=True)
        for h in (trusting, doubting):
            await wait_until(lambda: h.core.vocabulary and h.core.listening)

        async def command(h, text, expect):
            start = len(h.user.received)
            await h.user.say(h.core.address, text)
            return await h.user.wait_for(lambda t: expect in t, timeout=60, start=start)

        await command(trusting, "signedecho", "signed-echo finished")
        reply = await command(trusting, "unsignedecho", "could not get the application unsigned-echo")
        assert "sign" in reply.lower()
        reply = await command(doubting, "signedecho", "could not get the application signed-echo")
        assert "trust" in reply.lower() or "sign" in reply.lower()
    world.close()
