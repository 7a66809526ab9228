"""Per-agent credentials, ephemeral RApp accounts, tokens bound to their holder and kept across a
Platform restart, Store downloads that need a token (issue: RApps are untrusted code)."""
from __future__ import annotations

import asyncio
import os
import stat
import time

import pytest

from agents.base import RappAgent
from agents.errors import RequestRefused
from agents.identity import EphemeralAccounts
from agents.platform_agent import PlatformAgent
from agents.store_agent import StoreAgent
from ontology import platform as P
from ontology import store as S
from scenarios.system import wait_until
from xmpp_server.credentials import CredentialError, CredentialStore
from xmpp_server.probe import LoginError, probe_login, remove_account
from xmpp_server.settings import XmppSettings


def test_each_agent_gets_its_own_private_password(tmp_path):
    store = CredentialStore(tmp_path / "creds")
    a, b = store.password("core-nao1"), store.password("platform")
    assert a != b and len(a) >= 24
    assert store.password("core-nao1") == a  # kept
    assert stat.S_IMODE((tmp_path / "creds").stat().st_mode) == 0o700
    assert stat.S_IMODE(store.path("core-nao1").stat().st_mode) == 0o600


def test_a_password_file_others_can_read_is_refused(tmp_path):
    store = CredentialStore(tmp_path)
    store.password("store")
    os.chmod(store.path("store"), 0o644)
    with pytest.raises(CredentialError, match="chmod 600"):
        store.password("store")
    with pytest.raises(CredentialError, match="not an account name"):
        store.path("../etc/passwd")


def test_no_password_travels_in_a_child_environment(tmp_path):
    settings = XmppSettings.from_env({"RAPP_XMPP_PASSWORD": "deployer-secret"}, credentials_dir=tmp_path)
    assert settings.password_for("store") == "deployer-secret"
    env = settings.to_env()
    assert "deployer-secret" not in env.values() and "RAPP_XMPP_PASSWORD" not in env
    assert env["RAPP_CREDENTIALS_DIR"] == str(tmp_path)
    assert set(settings.to_env(fields=("host", "port"))) == {"RAPP_XMPP_HOST", "RAPP_XMPP_PORT"}


async def test_ephemeral_account_is_deleted_and_a_crash_leftover_swept(xmpp_server, tmp_path):
    s = xmpp_server.settings(credentials_dir=tmp_path)
    accounts = EphemeralAccounts(s, owner="core-x")
    ident = await accounts.create("dyn-x-app")
    assert ident.password not in repr(ident)
    await probe_login(s.host, s.port, s.domain, user=ident.name, password=ident.password, register=False)
    assert await accounts.delete(ident.name)
    with pytest.raises(LoginError):
        await probe_login(s.host, s.port, s.domain, user=ident.name, password=ident.password, register=False)
    # a crashed Core left one behind: the next instance, reading the same ledger, deletes it
    left = await accounts.create("dyn-x-app")
    assert stat.S_IMODE(accounts.ledger.stat().st_mode) == 0o600
    again = EphemeralAccounts(s, owner="core-x")
    assert await again.sweep(again.pending()) == [left.name]
    assert again.pending() == {}
    with pytest.raises(LoginError):
        await probe_login(s.host, s.port, s.domain, user=left.name, password=left.password, register=False)


async def test_prepared_accounts_are_taken_once_each_and_the_unused_deleted(xmpp_server, tmp_path):
    """The Platform keeps one made account per warm Cloud worker: a burst of starts only logs in."""
    s = xmpp_server.settings(credentials_dir=tmp_path)
    accounts = EphemeralAccounts(s, owner="platform-x")
    accounts.prepare("cloud-app", 3)
    accounts.prepare("cloud-app", 3)  # topped up to 3, not 3 more
    await wait_until(lambda: len(accounts.pending()) >= 3, timeout=10, what="three accounts made")
    await asyncio.sleep(0.3)
    made = accounts.pending()
    assert len(made) == 3
    taken = [accounts.take("cloud-app") for _ in range(2)]
    assert len({i.name for i in taken}) == 2 and {i.name for i in taken} <= set(made)  # made ahead, not now
    for ident in taken:
        await probe_login(s.host, s.port, s.domain, user=ident.name, password=ident.password, register=False)
    await accounts.close()  # the third, never taken, is deleted; the taken ones are their runs'
    assert set(accounts.pending()) == {i.name for i in taken}
    (spare,) = set(made) - {i.name for i in taken}
    with pytest.raises(LoginError):
        await probe_login(s.host, s.port, s.domain, user=spare, password=made[spare], register=False)
    for ident in taken:
        assert await accounts.delete(ident.name)
    assert accounts.pending() == {}
    # none made ahead: one reserved, in the ledger at once, on the server only once its holder registers it
    t0 = time.monotonic()
    reserved = accounts.take("cloud-app")
    assert time.monotonic() - t0 < 0.05 and reserved.name in accounts.pending()
    with pytest.raises(LoginError):
        await probe_login(s.host, s.port, s.domain, user=reserved.name, password=reserved.password, register=False)
    await probe_login(s.host, s.port, s.domain, user=reserved.name, password=reserved.password, register=True)
    assert await accounts.delete(reserved.name) and accounts.pending() == {}


async def test_embedded_server_removes_only_the_logged_in_account(xmpp_server):
    s = xmpp_server.settings()
    await probe_login(s.host, s.port, s.domain, user="keep-me", password="k", register=True)
    await probe_login(s.host, s.port, s.domain, user="drop-me", password="d", register=True)
    with pytest.raises(LoginError):  # wrong password: nothing removed
        await remove_account(s.host, s.port, s.domain, user="keep-me", password="wrong")
    await remove_account(s.host, s.port, s.domain, user="drop-me", password="d")
    await probe_login(s.host, s.port, s.domain, user="keep-me", password="k", register=False)


async def test_tokens_survive_a_platform_restart_and_bind_to_their_holder(settings, unique, tmp_path):
    name = unique("platform")
    platform = PlatformAgent(name, settings=settings, data_dir=tmp_path / "platform")
    owner, thief = RappAgent(unique("owner"), settings), RappAgent(unique("thief"), settings)
    await platform.start()
    await owner.start()
    await thief.start()
    try:
        await owner.request(platform.address, P.RegisterUser(user="ann", password="pw"))
        token = (await owner.request(platform.address, P.Login(user="ann", password="pw"))).token
        await platform.stop()
        assert stat.S_IMODE((tmp_path / "platform" / "users.db").stat().st_mode) == 0o600
        assert token.encode() not in (tmp_path / "platform" / "users.db").read_bytes()
        platform = PlatformAgent(name, settings=settings, data_dir=tmp_path / "platform")
        await platform.start()
        assert (await owner.request(platform.address, P.Ping(token=token))).user == "ann"
        with pytest.raises(RequestRefused, match="issued to another agent"):
            await thief.request(platform.address, P.Ping(token=token))
        with pytest.raises(RequestRefused, match="forbidden|cannot register"):
            await thief.request(platform.address, P.RegisterRobot(robot_id="r", robot_type="nao",
                                                                   core_jid=owner.address))
    finally:
        for agent in (owner, thief, platform):
            await agent.stop()


async def test_store_downloads_need_the_senders_platform_token(settings, unique, tmp_path):
    from agents.store_client import download_package, publish_package
    from ontology.package import build_package_bytes

    from .test_lifecycle import FIXTURE

    platform = PlatformAgent(unique("platform"), settings=settings, store=unique("store"))
    store = StoreAgent(platform.store.split("@")[0], tmp_path / "store", settings, platform=platform.address)
    owner, thief = RappAgent(unique("owner"), settings), RappAgent(unique("thief"), settings)
    for agent in (platform, store, owner, thief):
        await agent.start()
    try:
        await owner.request(store.address, S.RegisterOwner(owner="dev", password="pw"))
        await publish_package(owner, store.address, "dev", "pw", build_package_bytes(FIXTURE))
        # owner operations are decided on the sender: the owner's password alone is not enough
        with pytest.raises(RequestRefused, match="publishes from"):
            await thief.request(store.address, S.Delete(owner="dev", password="pw", name="echo-app"))
        with pytest.raises(RequestRefused, match="Platform token"):
            await download_package(thief, store.address, "echo-app")
        await owner.request(platform.address, P.RegisterUser(user="ann", password="pw"))
        token = (await owner.request(platform.address, P.Login(user="ann", password="pw"))).token
        with pytest.raises(RequestRefused, match="another agent"):
            await download_package(thief, store.address, "echo-app", token=token)
        info, data = await download_package(owner, store.address, "echo-app", token=token)
        assert info.name == "echo-app" and len(data) == info.size
    finally:
        for agent in (owner, thief, store, platform):
            await agent.stop()
