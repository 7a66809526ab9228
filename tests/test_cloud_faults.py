"""A Cloud Agent killed from outside (SIGKILL to its process) is noticed by the Platform and its
Dynamic Agent is told within 2 s (the SDK raises CloudAgentLost); where the manifest says the
cloud part is restartable, the Platform starts it once more under the same JID. A crash (SIGSEGV)
leaves the Cloud Agent's Python stack in the Platform's record of the loss, and the requests it was
working on (or the last one it took) in a file the record names."""
from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from agents.platform_agent import CLOUD_NICE
from agents.tracing import read_trace
from robots import RobotAPI, World
from scenarios.system import RappSystem

from .test_lifecycle import FIXTURE, variant, wait_until
from .test_warm_pool import thread_priorities


@pytest.fixture(scope="module")
async def system(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("cloud-faults")
    world = World.from_file("small", seed=7)
    # the Platform's own default (a Platform beside simulated robots leaves its Cloud Agents at 0)
    async with RappSystem(workdir, trace_file=workdir / "trace.jsonl", platform_kw={"cloud_nice": CLOUD_NICE}) as system:
        await system.publish(FIXTURE)
        await system.publish(variant(workdir, "cloud-lost", "cloudlost", use_cloud=True, behaviour="cloudwatch"))
        src = variant(workdir, "cloud-again", "cloudagain", use_cloud=True, behaviour="cloudwatch", seconds=4)
        (src / "manifest.yaml").write_text((src / "manifest.yaml").read_text() + "cloud_restartable: true\n")
        await system.publish(src)
        system.handle = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")))
        await wait_until(lambda: system.handle.core.vocabulary and system.handle.core.listening)
        yield system
    world.close()


async def _kill_cloud_of(system, keyword: str, rapp: str, sig=signal.SIGKILL) -> tuple[float, int]:
    user, start = system.handle.user, len(system.handle.user.received)
    await user.say(system.handle.core.address, keyword)
    await user.wait_for(lambda t: t.startswith(f"[{rapp}] watching cloud"), timeout=30, start=start)
    session = next(c for c in system.platform.clouds.values() if c.rapp == rapp)
    # serving, it runs CLOUD_NICE below the Platform (its own process only: the Platform's is untouched)
    own = os.getpriority(os.PRIO_PROCESS, 0)
    await wait_until(lambda: thread_priorities(session.process.pid) == {own + CLOUD_NICE}, 5)  # and its group
    assert os.getpriority(os.PRIO_PROCESS, 0) == own
    killed = time.time()  # the trace's clock
    os.kill(session.process.agent_pid, sig)  # the runtime itself (inside its sandbox: not the outer process)
    return killed, start


async def test_killed_cloud_agent_is_reported_to_its_dynamic_agent_within_2s(system):
    killed, start = await _kill_cloud_of(system, "cloudlost", "cloud-lost")
    user = system.handle.user
    await user.wait_for(lambda t: t.startswith("cloud-lost finished"), timeout=20, start=start)
    assert "[cloud-lost] cloud lost: cloud-lost" in user.texts()[start:]  # the RApp caught CloudAgentLost
    # told: the Dynamic Agent's own record of the Platform's notice (the owner's chat adds the
    # RApp's report and the Core's relay, which a loaded test machine may stall)
    told = next((r for r in read_trace(system.settings.trace_file) if r["kind"] == "structure"
                 and r["event"] == "cloud-down" and r["agent"].startswith("dyn-nao1-cloud-lost")), None)
    assert told is not None, "the Dynamic Agent recorded no cloud-down"
    assert told["t"] - killed <= 2.0, told["t"] - killed
    assert not any(c.rapp == "cloud-lost" for c in system.platform.clouds.values())


async def test_restartable_cloud_agent_is_started_once_more(system):
    # SIGSEGV as a crash in native code delivers it (a Cloud Agent's OpenCV work did so in a fleet run)
    killed, start = await _kill_cloud_of(system, "cloudagain", "cloud-again", signal.SIGSEGV)
    user = system.handle.user
    await user.wait_for(lambda t: t.startswith("cloud-again finished"), timeout=30, start=start)
    texts = user.texts()[start:]
    # calls go on: one in flight is answered by the new process (the server kept it) or fails
    # with "cloud-restarted" and the next succeeds; none is lost, the task ends well
    assert "[cloud-again] echo done for owner-nao1, doubled 42" in texts and "[cloud-again] cloud lost: cloud-lost" not in texts
    trace = read_trace(system.settings.trace_file)
    events = [r for r in trace if r["kind"] == "structure"]
    lost = next(r for r in events if r["event"] == "cloud-lost" and r["rapp"] == "cloud-again")
    assert lost["restart"] is True and lost["exit_code"] == -signal.SIGSEGV
    # where it crashed: the agent runtime's fault handler wrote its Python stack to stderr.log
    assert "Fatal Python error: Segmentation fault" in lost["stderr"] and "File " in lost["stderr"]
    # and what it was working on (or, idle, the last request it took), kept out of its run directory
    kept = json.loads(Path(lost["input"]).read_text())["requests"]
    assert kept[-1]["action"] == "double" and json.loads(kept[-1]["body"])["value"] == 21
    respawn = next(r for r in events if r["event"] == "cloud-spawn" and r.get("restart"))
    told = [r for r in events if r["event"] == "cloud-down" and r["cloud"] == respawn["cloud"]]
    # told twice: restarting, at once (however long the restart takes), then serving again
    assert [(r["restarting"], r["restarted"]) for r in told] == [(True, False), (False, True)], told
    assert told[0]["t"] - killed <= 2.0 and respawn["cloud"] == lost["cloud"]  # the same JID
