"""The RAPP lifecycle end to end on a real embedded server: command -> download -> Dynamic Agent
process -> robot and Platform calls -> finish -> destroy -> listening again (figs 2-5)."""
from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
from pathlib import Path

import pytest
import yaml

from agents.base import RappAgent
from agents.errors import RequestRefused, RequestTimeout
from agents.store_agent import StoreAgent
from agents.tracing import read_trace
from ontology import robot as R
from ontology.acl import Performative
from ontology import store as S
from robots import RobotAPI, World
from scenarios.system import RappSystem, wait_until
from xmpp_server import XmppSettings

from .test_warm_pool import gone

FIXTURE = Path(__file__).parent / "fixtures" / "echo_app"
SUPERVISING = {"supervisor", "core-service", "core-events", "user-listener", "microphone-listener", "audio-listener"}
SERVING = {"supervisor", "core-service", "core-events", "command-server", "busy-chat", "heartbeats", "safety"}


class SpyAPI:
    """The real robot API, recording which Core behaviours were active at each call."""

    def __init__(self, api: RobotAPI):
        self.api, self.core, self.calls = api, None, []
        self.microphone = api.microphone
        self.moving_forward, self.capabilities, self.halt = api.moving_forward, api.capabilities, api.halt
        # the Core cuts its own voice from what it hears by its loudspeaker's times (without them it
        # drops the pieces heard while it spoke, which a late piece escapes)
        self.protect, self.loudspeaker_timing = api.protect, api.loudspeaker_timing
        self.odometry_counters = api.odometry_counters

    async def handle(self, req):
        task = asyncio.current_task()
        if task is None or task.get_name() != "core-localizer":  # the Core's own odometry reads, every 0.1 s
            self.calls.append((req.action_name, set(self.core.active_behaviours()) if self.core else set()))
        return await self.api.handle(req)


def variant(tmp_path: Path, name: str, keyword: str, **params) -> Path:
    """A copy of the echo RApp under another name and keyword, with other default params."""
    dest = tmp_path / name
    shutil.copytree(FIXTURE, dest)
    manifest = yaml.safe_load((dest / "manifest.yaml").read_text())
    manifest.update(name=name, keywords=[keyword])
    manifest["params"].update(params)
    (dest / "manifest.yaml").write_text(yaml.safe_dump(manifest))
    return dest


@contextlib.asynccontextmanager
async def lifecycle_system(workdir: Path, settings: XmppSettings | None = None, variants=()):
    """A RappSystem tracing to workdir/trace.jsonl (on its own embedded server unless `settings`
    are given) with the echo RApp and the given `variant` arguments published, and one spied nao
    robot whose Core listens (system.spy, system.handle)."""
    world = World.from_file("small", seed=3)
    try:
        async with RappSystem(workdir, settings=settings, trace_file=workdir / "trace.jsonl") as system:
            await system.publish(FIXTURE)
            for name, keyword, params in variants:
                await system.publish(variant(workdir, name, keyword, **params))
            spy = SpyAPI(RobotAPI(world.add_robot("nao")))
            handle = await system.add_robot("nao", api=spy)
            spy.core = handle.core
            system.spy = spy
            system.handle = handle
            await wait_until(lambda: handle.core.vocabulary and handle.core.listening)
            yield system
    finally:
        world.close()


@pytest.fixture(scope="module")
async def system(tmp_path_factory):
    async with lifecycle_system(tmp_path_factory.mktemp("lifecycle"), variants=[
            ("echo-cloud", "cloudecho", {"use_cloud": True}),
            ("echo-fail", "failecho", {"behaviour": "raise"}),
            ("echo-slow", "slowecho", {"behaviour": "silent"})]) as system:
        yield system


def state(core) -> str:
    return core.supervisor.behaviour.current


async def run_command(system, text: str, expect: str, timeout=60.0) -> str:
    user = system.handle.user
    start = len(user.received)
    await user.say(system.handle.core.address, text)
    return await user.wait_for(lambda t: expect in t, timeout=timeout, start=start)


def structure(trace, agent_prefix=None):
    """The agents' structure records (not the XMPP server's logins and registrations)."""
    return [r for r in trace if r["kind"] == "structure" and not str(r.get("agent", "")).startswith("xmpp-server@")
            and (agent_prefix is None or r["agent"].startswith(agent_prefix))]


async def check_full_lifecycle(system) -> list[dict]:
    """One "echo" command through the whole lifecycle; returns the trace (shared with the
    Prosody test)."""
    core, spy = system.handle.core, system.spy
    assert core.active_behaviours() == SUPERVISING
    spy.calls.clear()
    await run_command(system, "echo", "echo-app finished")
    # the Dynamic Agent's robot calls ran while the Core served it, not while it supervised
    assert [c for c, _ in spy.calls if c in ("say", "get_global_pose")][:2] == ["say", "get_global_pose"]
    say_active = next(active for c, active in spy.calls if c == "say")
    assert say_active == SERVING
    # the Core is supervising again, and the Dynamic Agent and its process are gone
    await wait_until(lambda: core.listening)
    assert core.active_behaviours() == SUPERVISING and core.dynamic is None
    trace = read_trace(system.settings.trace_file)
    spawn = [r for r in structure(trace) if r["event"] == "spawn"][-1]
    await wait_until(lambda: gone(spawn["pid"]), 5)  # killed before the Core resumed, reaped just after

    def deleted() -> list:
        return [r for r in structure(read_trace(system.settings.trace_file))
                if r["event"] == "account-deleted" and r["account"] == spawn["dynamic"]]
    await wait_until(deleted, 10)  # after the reaping: its exit code is recorded there
    assert deleted()[0]["exit_code"] in (0, 143, -9), deleted()
    stopped = [r for r in trace if r["kind"] == "agent" and r["event"] == "stopped"
               and r["agent"] == spawn["dynamic"]]
    assert stopped, "the Dynamic Agent logged out"
    with pytest.raises(RequestTimeout):
        await core.request(spawn["dynamic"], R.GetGlobalPose(), timeout=0.5)
    assert "[echo-app] echo done for owner-nao1" in system.handle.user.texts()  # labelled: the RApp's words
    return trace


async def check_lifecycle_over_the_wire(system) -> tuple[list[dict], dict]:
    """check_full_lifecycle on an external server (Prosody, ejabberd): every message went through
    it, the Dynamic Agent pinged the Platform, and its one-run account was deleted through the
    server's in-band registration. Returns the trace and the run's spawn record."""
    trace = await check_full_lifecycle(system)
    spawn = [r for r in structure(trace) if r["event"] == "spawn"][-1]
    sent = [r for r in trace if r["kind"] == "message" and r["dir"] == "send"]
    assert sent and all(r["path"] == "xmpp" for r in sent)
    assert any(r["receiver"] == system.platform.address and r["sender"] == spawn["dynamic"]
               and r["action"] == "ping" for r in sent), "the Dynamic Agent pinged the Platform"
    await wait_until(lambda: any(r["event"] == "account-deleted" and r["account"] == spawn["dynamic"]
                                 for r in structure(read_trace(system.settings.trace_file))), timeout=10)
    return trace, spawn


async def test_full_lifecycle(system):
    await check_full_lifecycle(system)


async def test_cloud_agent_lives_and_dies_with_dynamic_agent(system):
    await run_command(system, "cloudecho", "echo-cloud finished")
    assert any("doubled 42" in t for t in system.handle.user.texts())
    trace = read_trace(system.settings.trace_file)
    events = [(r["event"], r.get("rapp")) for r in structure(trace)
              if r["event"] in ("spawn", "cloud-spawn", "cloud-destroy", "destroy")
              and r.get("rapp") == "echo-cloud"]
    assert events == [("spawn", "echo-cloud"), ("cloud-spawn", "echo-cloud"),
                      ("cloud-destroy", "echo-cloud"), ("destroy", "echo-cloud")]
    cloud = next(r for r in structure(trace) if r["event"] == "cloud-spawn" and r["rapp"] == "echo-cloud")
    await wait_until(lambda: gone(cloud["pid"]), 5)
    assert not system.platform.clouds


async def test_fig6_request_passes_and_s9_are_state_records(system):
    """Fig. 6: the Platform's own FSM goes s0 -> s1; each request is a pass s1 -> sX -> s1 of its own
    (s5 a sub-FSM: download, build, start). Fig. 5: each robot command is a pass of the s9 sub-FSM
    while the Core's FSM stays in s8; every state entered is a record carrying its request."""
    start = len(read_trace(system.settings.trace_file))
    await run_command(system, "cloudecho", "echo-cloud finished")
    trace = read_trace(system.settings.trace_file)
    platform, core = system.platform.address, system.handle.core.address
    states = [r for r in trace if r["kind"] == "state"]
    assert [r["state"] for r in states if r["agent"] == platform and r["fsm"] == "platform"
            and not r.get("conversation_id")] == ["s0_init", "s1_wait"]
    new = trace[start:]
    by_conv = {}
    for r in new:
        if r["kind"] == "state" and r.get("conversation_id") and r["agent"] == platform:
            by_conv.setdefault(r["conversation_id"], []).append((r["fsm"], r["state"]))
    sent = {r["conversation_id"]: r["action"] for r in new if r["kind"] == "message" and r["dir"] == "recv"
            and r["agent"] == platform and r["performative"] == "request"}
    paths = {sent[c]: p for c, p in by_conv.items() if c in sent}
    assert paths["start_cloud_agent"] == [("platform", "s5_create_cloud"), ("platform.s5_create_cloud", "download"),
                                          ("platform.s5_create_cloud", "build"), ("platform.s5_create_cloud", "start")]
    assert paths["release_cloud_agents"] == [("platform", "s6_destroy_cloud")]
    assert paths["issue_app_token"] == [("platform", "s2_register")]
    assert paths["cloud_ready"] == [("platform", "s2_register")]
    # every request the Platform took was one pass (the Store's token checks too)
    assert set(sent) <= set(by_conv), {sent[c] for c in set(sent) - set(by_conv)}
    commands = {r["conversation_id"]: r["action"] for r in new if r["kind"] == "message" and r["dir"] == "recv"
                and r["agent"] == core and r["ontology"] == "robot" and r["performative"] == "request"}
    s9 = {}
    for r in new:
        if r["kind"] == "state" and r["agent"] == core and r["fsm"] == "core.s9":
            s9.setdefault(r["conversation_id"], []).append(r["state"])
    assert commands and set(commands) == set(s9)
    assert all(s9[c] == ["lock", "act", "release"] for c in commands), s9
    # the Core's own FSM went through s8 once for the task, not once per command
    core_states = [r["state"] for r in new if r["kind"] == "state" and r["agent"] == core and r["fsm"] == "core"]
    assert core_states.count("s8_serve") == 1, core_states
    from scenarios.fsm_view import fsm_text
    drawn = fsm_text(trace)
    assert "s5_create_cloud[download > build > start]" in drawn and "core.s9: lock > act > release" in drawn, drawn


async def test_unknown_command_is_explained_and_core_keeps_listening(system):
    reply = await run_command(system, "please juggle three flaming torches", "did not understand")
    assert "juggle" in reply and reply.count("understand") == 1, reply
    await wait_until(lambda: system.handle.core.listening)
    await run_command(system, "echo", "echo-app finished")
    await run_command(system, "echo", "echo-app finished")


async def test_failing_task_is_reported_and_cleaned_up(system):
    reply = await run_command(system, "failecho", "echo-fail ended with a problem")
    assert "deliberate failure" in reply
    await wait_until(lambda: system.handle.core.active_behaviours() == SUPERVISING)


async def test_robot_request_from_other_agent_is_refused(system):
    intruder = RappAgent("intruder", system.settings)
    await intruder.start()
    try:
        with pytest.raises(RequestRefused, match="does not serve robot/move_to"):
            await intruder.request(system.handle.core.address, R.MoveTo(x=1.0, y=0.0), timeout=20)
        # while a Dynamic Agent supervises, an intruder is refused by the command server itself
        slow = asyncio.create_task(run_command(system, "slowecho", "echo-slow ended with a problem"))
        await wait_until(lambda: "command-server" in system.handle.core.active_behaviours())
        with pytest.raises(RequestRefused, match="not the current supervisor"):
            await intruder.request(system.handle.core.address, R.MoveTo(x=1.0, y=0.0), timeout=20)
        await system.handle.user.say(system.handle.core.address, "cancel")
        assert "cancelled by the user" in await slow
    finally:
        await intruder.stop()


async def test_trace_shows_structure_changes_in_order(system):
    trace = read_trace(system.settings.trace_file)
    core = system.handle.core.address
    events = structure(trace)
    assert events[0]["event"] == "publish" and any(r["event"] == "register" for r in events)
    first = next(i for i, r in enumerate(events) if r["event"] == "download" and r.get("rapp") == "echo-cloud")
    last = next(i for i, r in enumerate(events) if i > first and r["event"] == "resume")
    order = [r["event"] for r in events[first:last + 1]]
    # Store serves the Core; a_dyn starts (Init) and takes over; Working; the Platform fetches
    # the cloud part and spawns a_cloud; it is destroyed with its account; Finished; a_dyn
    # destroyed; supervision back. The accounts are deleted after (in the background), checked below.
    expected = ["download", "download", "spawn", "status", "handoff", "status", "download",
                "cloud-spawn", "cloud-destroy", "status", "ended", "destroy", "resume"]
    assert [e for e in order if e != "account-deleted"] == expected, " ".join(order)
    spawn = next(r for r in events[first:] if r["event"] == "spawn")  # an earlier run's account may be deleted between
    cloud = next(r for r in events[first:] if r["event"] == "cloud-spawn")
    await wait_until(lambda: {spawn["dynamic"], cloud["cloud"]} <= {
        r["account"] for r in structure(read_trace(system.settings.trace_file))[first:]
        if r["event"] == "account-deleted"}, timeout=10, what="both one-run accounts deleted")
    later = structure(read_trace(system.settings.trace_file))[first:]
    destroyed = next(i for i, r in enumerate(later) if r["event"] == "cloud-destroy")
    assert any(r["event"] == "account-deleted" and r["account"] == cloud["cloud"] for r in later[destroyed:]), \
        "the Cloud Agent's account is deleted after its process ended"
    calls = [r for r in trace if r["kind"] == "message" and r["dir"] == "send"
             and r["receiver"] == core and r["ontology"] == "robot"]
    assert calls, "robot-API calls are in the trace"


async def test_store_data_survives_restart(xmpp_server, tmp_path, unique):
    settings = xmpp_server.settings()
    from ontology.package import build_package_bytes
    from agents.store_client import publish_package

    name = unique("store")
    client = RappAgent(unique("dev"), settings)  # downloads as the Platform would (no token)
    store = StoreAgent(name, tmp_path / "store", settings, platform=client.address)
    await store.start()
    await client.start()
    await client.request(store.address, S.RegisterOwner(owner="dev", password="pw"))
    await publish_package(client, store.address, "dev", "pw", build_package_bytes(FIXTURE))
    await store.stop()
    again = StoreAgent(name, tmp_path / "store", settings, platform=client.address)
    await again.start()
    try:
        listed = await client.request(again.address, S.ListPackages(robot_type="nao"))
        assert [p.name for p in listed.packages] == ["echo-app"]
        info = await client.request(again.address, S.DownloadBegin(name="echo-app"))
        assert info.version == "1.0.0" and info.size > 0
    finally:
        await again.stop()
        await client.stop()


async def test_in_process_mode_runs_the_same_package_bytes(system):
    """The same download, verification, unpacking and runtime code, as a task of the Core's process
    (Dynamic Agent) and of the Platform's (Cloud Agent): one spawn mechanism, two modes."""
    world = World.from_file("small", seed=8)
    handle = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")), robot_id="nao-inproc",
                                    dynamic_mode="inprocess")
    system.platform.cloud_mode = "inprocess"
    try:
        await wait_until(lambda: handle.core.vocabulary and handle.core.listening)
        for _ in range(2):  # twice: the second run imports the RApp again from its new directory
            start = len(handle.user.received)
            await handle.user.say(handle.core.address, "cloudecho")
            await handle.user.wait_for(lambda t: "echo-cloud finished" in t, timeout=60, start=start)
        assert any("doubled 42" in t for t in handle.user.texts())
        spawns = [r for r in structure(read_trace(system.settings.trace_file))
                  if r["event"] == "spawn" and r["dynamic"].startswith("dyn-nao-inproc")]
        assert len(spawns) == 2 and all(r["pid"] == os.getpid() and not r["sandbox"] for r in spawns)
        clouds = [r for r in structure(read_trace(system.settings.trace_file))
                  if r["event"] == "cloud-spawn" and r["owner"].startswith("dyn-nao-inproc")]
        assert len(clouds) == 2 and all(r["pid"] == os.getpid() for r in clouds)
        await wait_until(lambda: handle.core.active_behaviours() >= {"supervisor", "user-listener"})
        await wait_until(lambda: not system.platform.clouds, what="in-process Cloud Agents destroyed")
    finally:
        system.platform.cloud_mode = "process"
        world.close()


async def test_command_heard_through_the_robots_microphone(system):
    core = system.handle.core
    await wait_until(lambda: "microphone-listener" in core.active_behaviours())
    start = len(system.handle.user.received)
    core.robot.api.robot.microphone.hear("echo")  # the user speaks to the robot
    await system.handle.user.wait_for(lambda t: "echo-app finished" in t, timeout=60, start=start)
    commands = [r for r in read_trace(system.settings.trace_file)
                if r["kind"] == "structure" and r["event"] == "command"]
    assert commands[-1]["text"] == "echo"


async def test_core_learns_of_rapps_published_and_removed_while_it_runs(system, tmp_path):
    """The Store tells subscribed Cores (FIPA subscribe) of each publish and removal."""
    core = system.handle.core
    await system.publish(variant(tmp_path, "late-echo", "lateecho"))
    await wait_until(lambda: "lateecho" in core.vocabulary, timeout=5, what="vocabulary refreshed")
    await run_command(system, "lateecho", "late-echo finished")
    await system.publisher.request(system.store.address, S.Delete(owner="developer", password="developer-secret",
                                                                   name="late-echo"))
    await wait_until(lambda: "lateecho" not in core.vocabulary, timeout=5, what="removal seen")
    assert any(r["event"] == "catalogue-changed" for r in structure(read_trace(system.settings.trace_file)))


async def test_core_answers_while_the_robot_is_still_speaking(system):
    """Speech runs beside listening: a long sentence does not delay the next command's answer."""
    core = system.handle.core
    await wait_until(lambda: core.listening and "user-listener" in core.active_behaviours())
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    await core.tell_user("this is a long sentence of twenty words " * 3)  # ~8 s of speech
    assert loop.time() - t0 < 0.5
    user, start = system.handle.user, len(system.handle.user.received)
    t0 = loop.time()
    await user.say(core.address, "please juggle three torches")
    await user.wait_for(lambda t: t.startswith("Sorry"), timeout=10, start=start)
    assert loop.time() - t0 < 1.0, "the command was answered while the robot spoke"


async def test_the_owner_is_told_each_commands_end_as_a_typed_record(system):
    """Results as data (ontology/results.py): the owner's client subscribes once; each command's end
    comes as a TaskRecord (reports with their data, state, reason, stage, times), whether the task
    finished, failed, or never started; none of it is chat, and only the owner may subscribe."""
    from agents.errors import RequestRefused as Refused
    from ontology.results import SubscribeTasks, TaskStage

    core, user = system.handle.core, system.handle.user
    await user.watch_tasks(core.address)
    start = len(user.ended)
    await run_command(system, "echo", "echo-app finished")
    done = await user.task_end(30, start)
    assert (done.rapp, done.stage, done.state, done.ok, done.command) == ("echo-app", TaskStage.RUN, "Finished", True,
                                                                          "echo")
    assert [r.text for r in done.reports] == ["echo done for owner-nao1"] and done.told == "echo-app finished."
    assert done.started < done.reports[0].stamp <= done.ended and not done.refusals
    assert [r.report.text for r in user.reported[-1:]] == ["echo done for owner-nao1"]  # each report as it came

    await run_command(system, "failecho", "echo-fail ended with a problem")
    failed = await user.task_end(30, start + 1)
    assert (failed.rapp, failed.stage, failed.state, failed.ok) == ("echo-fail", TaskStage.RUN, "Error", False)
    assert "deliberate failure" in failed.reason

    await run_command(system, "please juggle three flaming torches", "did not understand")
    await wait_until(lambda: len(user.ended) > start + 2, 10)  # told when the Core listens again
    never = user.ended[start + 2]
    assert (never.rapp, never.stage, never.ok, never.started) == ("", TaskStage.UNDERSTAND, False, None)
    assert "juggle" in never.reason and never.command == "please juggle three flaming torches"
    assert not [t for t in user.texts() if t.startswith("{")] and not user.bad  # records are not chat

    intruder = RappAgent("intruder-tasks", system.settings)
    await intruder.start()
    try:
        with pytest.raises(Refused, match="not the owner"):
            await intruder.request(core.address, SubscribeTasks(), performative=Performative.SUBSCRIBE, timeout=20)
    finally:
        await intruder.stop()
