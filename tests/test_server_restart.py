"""The XMPP server restarts in the middle of a task: agents reconnect with back-off, reads are
retried, the task ends completed or cleanly failed (never stuck), every request has an outcome."""
from __future__ import annotations

import asyncio


from agents.tracing import read_trace
from robots import RobotAPI, World
from scenarios.system import RappSystem

from .test_lifecycle import FIXTURE, SUPERVISING, state, variant, wait_until


async def test_server_restart_mid_task(tmp_path):
    world = World.from_file("small", seed=7)
    async with RappSystem(tmp_path, trace_file=tmp_path / "trace.jsonl", force_xmpp=True) as system:
        await system.publish(variant(tmp_path, "poll-echo", "pollecho", behaviour="poll", seconds=8))
        await system.publish(FIXTURE)
        h = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")))
        await wait_until(lambda: h.core.vocabulary and state(h.core) == "s3_listen")
        await h.user.say(h.core.address, "pollecho")
        await wait_until(lambda: "command-server" in h.core.active_behaviours())
        await asyncio.sleep(1.5)
        await asyncio.to_thread(system.server.stop)
        await asyncio.sleep(0.5)
        await system.server.astart()
        end = await h.user.wait_for(lambda t: "poll-echo finished" in t or "poll-echo ended" in t, timeout=60)
        await wait_until(lambda: h.core.active_behaviours() == SUPERVISING and state(h.core) == "s3_listen")
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


async def test_embedded_server_hashes_passwords_with_fewer_rounds_and_reads_old_hashes(tmp_path):
    """New accounts are stored with PASSWORD_ROUNDS PBKDF2 iterations (login and registration cost
    ~1 ms, not ~35); an account stored with pyjabber's own 100 000 still logs in."""
    import sqlite3

    import binascii
    import hashlib

    from xmpp_server import EmbeddedServer
    from xmpp_server.embedded import PASSWORD_ROUNDS
    from xmpp_server.probe import LoginError, probe_login

    db = tmp_path / "server.db"
    async with EmbeddedServer(db=db) as server:
        await probe_login(server.host, server.port, server.domain, user="fresh", password="pw")
    salt = b"salt-of-old-acct"
    digest = hashlib.pbkdf2_hmac("sha256", b"old-pw", salt, 100000)  # as pyjabber stores it
    old = f"sha256$100000${binascii.hexlify(salt).decode()}${binascii.hexlify(digest).decode()}"
    with sqlite3.connect(db) as con:
        stored = dict(con.execute("select jid, hash_pwd from credentials"))
        assert stored["fresh"].startswith(f"sha256${PASSWORD_ROUNDS}$")
        con.execute("insert into credentials (jid, hash_pwd) values (?, ?)", ("old", old))
    async with EmbeddedServer(db=db) as server:
        await probe_login(server.host, server.port, server.domain, user="old", password="old-pw", register=False)
        await probe_login(server.host, server.port, server.domain, user="fresh", password="pw", register=False)
        try:
            await probe_login(server.host, server.port, server.domain, user="old", password="wrong", register=False)
        except LoginError:
            pass
        else:
            raise AssertionError("a wrong password logged in")


async def test_chat_user_keeps_its_connection_past_the_servers_silence_timeout():
    """pyjabber drops a client silent for `connection_timeout` seconds and keeps the dropped
    connection listed as online; a message to the bare JID during the reconnection was lost (a
    hazard run waited forever for "finished"). The chat user's keep-alive pings prevent the drop."""
    from scenarios.user import ChatUser
    from xmpp_server import EmbeddedServer

    async with EmbeddedServer(connection_timeout=2) as server:
        settings = server.settings()
        quiet = ChatUser("quiet-user", settings, keepalive_s=0.5)
        other = ChatUser("other-user", settings, keepalive_s=0.5)
        await quiet.start()
        await other.start()
        first = str(quiet.boundjid)
        try:
            await asyncio.sleep(4.5)  # more than twice the timeout without a message
            assert str(quiet.boundjid) == first  # same connection, never re-bound
            await other.say("quiet-user", "still there?")
            assert await quiet.wait_for(lambda t: t == "still there?", timeout=5) == "still there?"
        finally:
            await quiet.stop()
            await other.stop()
