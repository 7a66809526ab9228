"""The full RAPP lifecycle against a real, private Prosody (not the embedded pyjabber server).

Opt-in by installation: skipped with a reason when the `prosody` binary is missing
(`apt-get install prosody`). Prosody differs from pyjabber where it matters: STARTTLS is required,
and it stamps full JIDs (user@domain/resource) on `from`, so this checks the agents compare bare
JIDs along the whole path (user command -> Dynamic Agent process -> robot.say + Platform ping ->
finished -> Core listening again).
"""
from __future__ import annotations

import asyncio

import pytest

from tests.test_lifecycle import check_lifecycle_over_the_wire, lifecycle_system, run_command
from xmpp_server.prosody import ProsodyServer, prosody_binary

pytestmark = [
    pytest.mark.prosody,
    pytest.mark.skipif(prosody_binary() is None,
                       reason="prosody is not installed (apt-get install prosody); "
                              "the real-server lifecycle test needs it"),
]


@pytest.fixture(scope="module")
async def prosody():
    async with ProsodyServer() as server:
        yield server


@pytest.fixture(scope="module")
async def system(prosody, tmp_path_factory):
    workdir = tmp_path_factory.mktemp("prosody-lifecycle")
    settings = prosody.settings(trace_file=workdir / "trace.jsonl", force_xmpp=True)
    async with lifecycle_system(workdir, settings) as system:
        yield system


async def test_prosody_accepts_prosodyctl_accounts(prosody):
    from xmpp_server.probe import probe_login

    prosody.register("ctl-user", "ctl-pw")
    await probe_login(prosody.host, prosody.port, prosody.domain, user="ctl-user",
                      password="ctl-pw", register=False, timeout=5)


async def test_full_lifecycle_on_prosody(system):
    # everything went through Prosody; the run's account was deleted through its in-band registration
    await check_lifecycle_over_the_wire(system)
    # the core is listening again: a second command runs too
    await run_command(system, "echo", "echo-app finished")


async def test_prosody_without_in_band_registration(tmp_path):
    from xmpp_server.probe import LoginError, probe_login

    async with ProsodyServer(workdir=tmp_path / "prosody", allow_registration=False) as srv:
        assert srv.settings().auto_register is False
        with pytest.raises(LoginError):
            await probe_login(srv.host, srv.port, srv.domain, user="nobody", timeout=3)
        srv.register("store", "rapp-secret")
        await probe_login(srv.host, srv.port, srv.domain, user="store", password="rapp-secret",
                          register=False, timeout=5)
        assert 'c2s_interfaces = { "127.0.0.1" }' in srv.config_file.read_text()
    assert not srv.running()


async def test_a_request_to_an_agent_not_yet_online_is_sent_again_until_heard(prosody, tmp_path):
    """Prosody (no offline storage here) silently drops a message to an agent that is not online.
    A request to a peer never heard from is sent again every second until the peer answers: the
    startup race the Store's first register_owner lost under load."""
    from agents.base import RappAgent
    from agents.responder import Responder
    from agents.tracing import read_trace
    from tests.test_messaging import Add, _add

    class Calc(RappAgent):
        async def setup(self):
            responder = Responder("test-math", {"add": _add})
            self.activate("math", responder, responder.make_template())

    settings = prosody.settings(force_xmpp=True, trace_file=tmp_path / "trace.jsonl")
    late = Calc("late-calc", settings)
    await late.start()  # the account exists; the agent then goes offline
    await late.stop()
    asker = RappAgent("asker", settings)
    await asker.start()

    async def come_online_later():
        await asyncio.sleep(0.8)
        agent = Calc("late-calc", settings)
        await agent.start()
        return agent

    coming = asyncio.ensure_future(come_online_later())
    try:
        assert (await asker.request(late.address, Add(a=1, b=2), timeout=8, retries=0)).total == 3
    finally:
        await (await coming).stop()
        await asker.stop()
    kinds = [r["kind"] for r in read_trace(tmp_path / "trace.jsonl")]
    assert "resend" in kinds
