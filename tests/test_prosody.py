"""The full RAPP lifecycle against a real, private Prosody (not the embedded pyjabber server).

Opt-in by installation: skipped with a reason when the `prosody` binary is missing
(`apt-get install prosody`). Prosody differs from pyjabber where it matters: STARTTLS is required,
and it stamps full JIDs (user@domain/resource) on `from`, so this checks the agents compare bare
JIDs along the whole path (user command -> Dynamic Agent process -> robot.say + Platform ping ->
finished -> Core listening again).
"""
from __future__ import annotations

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
