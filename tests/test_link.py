"""A flaky link between a robot and its server (xmpp_server/link.py, issue 48.4): the faults on real
sockets, then a RApp run whose robot's link is slow, lossy and goes away for 5 s."""
from __future__ import annotations

import asyncio
import math
import shutil
import time
from pathlib import Path

import pytest
import yaml

from agents.tracing import read_trace
from xmpp_server.link import RTO_S, FaultyLink, LinkFaults

ROOT = Path(__file__).resolve().parent.parent


async def echo_server():
    async def echo(reader, writer):
        try:
            while data := await reader.read(65536):
                writer.write(data)
                await writer.drain()
        except ConnectionError:
            pass
        writer.close()

    server = await asyncio.start_server(echo, "127.0.0.1", 0)
    return server, server.sockets[0].getsockname()[1]


async def round_trip(reader, writer, line: bytes, timeout: float = 10.0) -> float:
    t0 = time.monotonic()
    writer.write(line)
    await writer.drain()
    assert await asyncio.wait_for(reader.readexactly(len(line)), timeout) == line
    return time.monotonic() - t0


def test_faults_parse_and_refuse_nonsense():
    f = LinkFaults.parse("delay=80ms,jitter=30ms,loss=2%,outage=5s@40s,drop", seed=7)
    assert (f.delay_s, f.jitter_s, f.loss, f.outages, f.kind, f.seed) == (0.08, 0.03, 0.02, ((40.0, 5.0),), "drop", 7)
    assert LinkFaults.parse("") == LinkFaults()
    assert f.describe()["outages"] == [[40.0, 5.0]]
    for bad, why in [("delay=fast", "duration"), ("loss=150%", "share"), ("wobble=1", "unknown fault"),
                     ("outage=0s@3", "lasts")]:
        with pytest.raises(ValueError, match=why):
            LinkFaults.parse(bad)


async def test_delay_jitter_and_loss_keep_every_byte_in_order():
    server, port = await echo_server()
    async with FaultyLink(("127.0.0.1", port), LinkFaults(delay_s=0.05, jitter_s=0.02, loss=0.2, seed=3)) as link:
        reader, writer = await asyncio.open_connection(*link.address)
        rtts = [await round_trip(reader, writer, f"line {i}\n".encode()) for i in range(30)]
        writer.close()
    server.close()
    assert min(rtts) >= 0.03  # each way held about 50 ms
    assert link.stats.lost > 0 and max(rtts) >= RTO_S  # a lost chunk waits for TCP's resend
    assert link.stats.chunks == 60 and link.stats.connections == 1


async def test_a_hold_outage_delays_and_a_drop_outage_resets_and_refuses():
    server, port = await echo_server()
    async with FaultyLink(("127.0.0.1", port)) as link:
        reader, writer = await asyncio.open_connection(*link.address)
        assert await round_trip(reader, writer, b"before\n") < 0.5
        held = link.outage(1.0, "hold")
        assert 0.8 < await round_trip(reader, writer, b"during\n") < 3.0  # waits, then arrives: nothing lost
        await held
        dropped = link.outage(1.0, "drop")
        await asyncio.sleep(0.1)
        with pytest.raises((ConnectionError, asyncio.IncompleteReadError)):
            await round_trip(reader, writer, b"gone\n", timeout=3)
        r2, w2 = await asyncio.open_connection(*link.address)  # accepted by the kernel, then cut
        with pytest.raises((ConnectionError, asyncio.IncompleteReadError)):
            await round_trip(r2, w2, b"refused\n", timeout=3)
        await dropped
        r3, w3 = await asyncio.open_connection(*link.address)
        assert await round_trip(r3, w3, b"after\n") < 0.5
        w3.close()
    server.close()
    assert link.stats.refused == 1 and link.stats.reset >= 2 and len(link.stats.outages_done) == 2


@pytest.mark.timeout(240)
async def test_a_rapp_run_over_a_flaky_link_ends_right_with_nothing_lost(tmp_path):
    """The robot's Core and Dynamic Agent reach the server over 40 ms ± 20 ms with 2 % loss; while the
    robot drives, the link goes away for 5 s (connections reset). The drive goes on on the robot (its
    Core owns the motion), the agents reconnect and resend what was pending, each request runs once,
    the RApp's report and the task's end reach the owner."""
    from scenarios.home_setup import home_description, scenario_world
    from scenarios.recorder import RecordingAPI
    from scenarios.runner import Owner, Run
    from robots import RobotAPI

    world = scenario_world("small", 1, render="inline")
    try:
        api = RecordingAPI(RobotAPI(world.add_robot("elektron")),
                           frames_dir=tmp_path / "frames")
        owner = Owner("elektron", api, "owner-elektron1", "drive", home=home_description(world, "small", tmp_path),
                      core_kw={"dynamic_mode": "inprocess"},
                      link=LinkFaults(delay_s=0.04, jitter_s=0.02, loss=0.02, kind="drop", seed=11))
        moved_during: list[float] = []
        links: list[FaultyLink] = []

        async def cut_while_driving(run: Run) -> None:
            start = api.robot.pose[:2]
            while math.dist(start, api.robot.pose[:2]) < 0.05:  # the drive has begun on the robot
                await asyncio.sleep(0.05)
            link = run.system.links["elektron1"]
            links.append(link)
            before = api.robot.pose[:2]
            await link.outage(5.0)
            moved_during.append(math.dist(before, api.robot.pose[:2]))

        rapp = tmp_path / "drive_check"  # the rover's test RApp, for an Elektron
        shutil.copytree(ROOT / "tests" / "fixtures" / "rover_check", rapp)
        manifest = yaml.safe_load((rapp / "manifest.yaml").read_text())
        manifest.update(robot_types=["elektron"], keywords=["drive"])
        (rapp / "manifest.yaml").write_text(yaml.safe_dump(manifest))
        run = Run(tmp_path / "run", world, rapp, [owner],
                  platform_kw={"service_workers": 0})
        await run.run(timeout_s=150, during=cut_while_driving)
        assert run.ok(owner), run.reason(owner)
        report = owner.reports[-1].data
        assert math.dist(api.robot.pose[:2], report["goal"]) < 0.3
    finally:
        world.close()
    assert moved_during and moved_during[0] > 0.1, moved_during  # the robot drove on while cut off
    stats = links[0].stats
    assert stats.reset >= 2 and stats.lost > 0 and stats.connections >= 4, stats  # the Core and its Dynamic, twice
    records = read_trace(run.trace)
    core = owner.handle.core.address
    events = [(r["event"], r["agent"]) for r in records if r["kind"] == "agent"]
    assert ("disconnected", core) in events and ("reconnected", core) in events
    executed = [r for r in records if r["kind"] == "message" and r["dir"] == "recv" and r["agent"] == core
                and r.get("action") == "move_along_path" and r.get("performative") == "request"]
    assert len({r["conversation_id"] for r in executed}) == 1, executed  # one drive, whatever was resent
