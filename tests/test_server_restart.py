"""The XMPP server restarts in the middle of a task: agents reconnect with back-off, reads are
retried, the task ends completed or cleanly failed (never stuck), every request has an outcome."""
from __future__ import annotations

import asyncio


from agents.tracing import read_trace
from robots import RobotAPI, World
from scenarios.system import RappSystem

from .test_lifecycle import FIXTURE, SUPERVISING, variant, wait_until


async def test_server_restart_mid_task(tmp_path):
    world = World.from_file("small", seed=7)
    async with RappSystem(tmp_path, trace_file=tmp_path / "trace.jsonl", force_xmpp=True) as system:
        await system.publish(variant(tmp_path, "poll-echo", "pollecho", behaviour="poll", seconds=8))
        await system.publish(FIXTURE)
        h = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")))
        await wait_until(lambda: h.core.vocabulary and h.core.listening)
        await h.user.say(h.core.address, "pollecho")
        await wait_until(lambda: "command-server" in h.core.active_behaviours())
        await asyncio.sleep(1.5)
        await asyncio.to_thread(system.server.stop)
        await asyncio.sleep(0.5)
        await system.server.astart()
        end = await h.user.wait_for(lambda t: "poll-echo finished" in t or "poll-echo ended" in t, timeout=60)
        await wait_until(lambda: h.core.active_behaviours() == SUPERVISING and h.core.listening)
        start = len(h.user.received)
        await h.user.say(h.core.address, "echo")
        await h.user.wait_for(lambda t: "echo-app finished" in t, timeout=60, start=start)

    trace = read_trace(tmp_path / "trace.jsonl")
    events = {(r["agent"], r["event"]) for r in trace if r["kind"] == "agent"}
    assert (h.core.address, "reconnected") in events
    assert any(a.startswith("dyn-") and e == "reconnected" for a, e in events) or "ended" in end
    # every request sent has an outcome: an answer in its conversation or a recorded timeout
    answers = {r["conversation_id"] for r in trace if r["kind"] == "message" and r["dir"] == "recv"
               and r["performative"] in ("inform", "failure", "refuse", "not-understood")}
    timeouts = {r["conversation_id"] for r in trace if r["kind"] == "timeout"}
    requests = [r for r in trace if r["kind"] == "message" and r["dir"] == "send" and r["performative"] == "request"]
    lost = [r for r in requests if r["conversation_id"] not in answers | timeouts]
    # requests whose sender was stopped while waiting are the only other legitimate ending
    stopped_waiting = {r["agent"] for r in trace if r["kind"] == "agent" and r["event"] == "stopped"}
    assert all(r["agent"] in stopped_waiting for r in lost), lost[:3]
    world.close()



async def test_a_warm_cloud_worker_idle_through_a_server_restart_still_serves(tmp_path):
    """The Platform's warm Cloud workers hold an XMPP session while idle (agents/warm_pool.py
    login=): one that waited through a restart of the server reconnects, and the next Cloud Agent
    start handed to it serves as if nothing happened."""
    world = World.from_file("small", seed=7)
    async with RappSystem(tmp_path, trace_file=tmp_path / "trace.jsonl") as system:
        await system.publish(variant(tmp_path, "cloud-echo", "cloudecho", use_cloud=True))
        h = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")))
        await wait_until(lambda: h.core.vocabulary and h.core.listening)
        await h.user.say(h.core.address, "cloudecho")  # the first Cloud Agent starts cold, the pool fills
        await h.user.wait_for(lambda t: "cloud-echo finished" in t, timeout=60)
        await wait_until(lambda: h.core.listening)
        pool = system.platform.warm_pool
        await pool.wait_ready(60)
        [worker] = pool.idle
        await asyncio.to_thread(system.server.stop)
        await asyncio.sleep(0.5)
        await system.server.astart()
        jid = system.settings.jid(worker.login.name)
        await wait_until(lambda: any(r["kind"] == "agent" and r["event"] == "reconnected" and r["agent"] == jid
                                     for r in read_trace(tmp_path / "trace.jsonl")), 30)
        start = len(h.user.received)
        await h.user.say(h.core.address, "cloudecho")
        await h.user.wait_for(lambda t: "cloud-echo finished" in t, timeout=60, start=start)
    spawns = [r for r in read_trace(tmp_path / "trace.jsonl") if r["kind"] == "structure" and r["event"] == "cloud-spawn"]
    assert [r.get("warm") for r in spawns] == [False, True] and spawns[1]["cloud"] == jid
    world.close()
