"""Rights: manifest permissions (robot-API groups, Platform services), emergency stop and resume,
the safety distance, resource locks, and package signatures checked by the Core."""
from __future__ import annotations

import asyncio

import pytest
import yaml

from agents.locks import LockError, ResourceLocks
from agents.tracing import read_trace
from ontology.package import build_package_bytes, generate_keypair
from robots import RobotAPI, World
from scenarios.system import RappSystem

from .test_lifecycle import FIXTURE, SUPERVISING, run_command, state, variant, wait_until


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
        system.world = world
        system.handle = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")))
        await wait_until(lambda: system.handle.core.vocabulary and state(system.handle.core) == "s3_listen")
        yield system
    world.close()


async def test_undeclared_robot_group_is_refused(system):
    reply = await run_command(system, "muteecho", "mute-echo ended with a problem")
    assert "did not declare the robot-API group 'navigation'" in reply


async def test_undeclared_service_is_refused(system):
    reply = await run_command(system, "greedyecho", "greedy-echo ended with a problem")
    assert "did not declare the service 'path_planning_list_maps'" in reply


async def test_user_stop_halts_and_latches_until_resume(system):
    core = system.handle.core
    task = asyncio.create_task(run_command(system, "driveecho", "drive-echo ended with a problem"))
    await wait_until(lambda: any(c for c in core.told if c == "echo") or
                     "command-server" in core.active_behaviours())
    await asyncio.sleep(0.5)  # driving now
    await system.handle.user.say(core.address, "stop")
    reply = await task
    assert "stopped by the user" in reply
    pose_after_stop = system.world.ground_truth().robots["nao"]
    await asyncio.sleep(0.3)
    assert system.world.ground_truth().robots["nao"] == pose_after_stop  # nothing moves
    # latched: the next task may not move the robot
    reply = await run_command(system, "driveecho", "drive-echo ended with a problem")
    assert "emergency stop" in reply
    await run_command(system, "resume", "I may move again")
    assert core.estop_reason is None
    await run_command(system, "echo", "echo-app finished")


async def test_obstacle_within_safety_distance_latches_estop(system):
    core = system.handle.core
    await run_command(system, "driveecho", "Emergency stop: obstacle ahead", timeout=60)
    assert core.estop_reason and "obstacle" in core.estop_reason
    trace = read_trace(system.settings.trace_file)
    assert any(r["kind"] == "structure" and r["event"] == "estop" and "obstacle" in r["reason"] for r in trace)
    await system.handle.user.wait_for(lambda t: "drive-echo ended" in t, timeout=30)
    await wait_until(lambda: core.active_behaviours() == SUPERVISING)
    await run_command(system, "resume", "I may move again")


async def test_velocity_driving_is_watched_by_the_safety_monitor(system):
    core = system.handle.core
    await run_command(system, "cruiseecho", "Emergency stop: obstacle ahead", timeout=60)
    pose = system.world.ground_truth().robots["nao"]
    await asyncio.sleep(0.3)
    assert system.world.ground_truth().robots["nao"] == pose  # halted, and stays halted
    await run_command(system, "stop", "cruise-echo ended with a problem")
    await wait_until(lambda: core.active_behaviours() == SUPERVISING)
    await run_command(system, "resume", "I may move again")


async def test_resource_lock_held_by_core_behaviour_is_refused_to_rapp(system):
    core = system.handle.core
    assert core.locks.try_lock("camera", "core:calibration")
    try:
        await run_command(system, "lockecho", "lock camera: held=False holder=core:calibration")
        await system.handle.user.wait_for(lambda t: "lock-echo finished" in t, timeout=30)
    finally:
        core.locks.free("camera", "core:calibration")
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
            await wait_until(lambda: h.core.vocabulary and state(h.core) == "s3_listen")

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
