"""The embedded server's own settings, against the real server in its process: password hashing
cost, and how long a silent client stays connected."""
from __future__ import annotations

import asyncio
import binascii
import hashlib
import sqlite3

import pytest

from scenarios.user import ChatUser
from xmpp_server import EmbeddedServer
from xmpp_server.compat import PASSWORD_ROUNDS
from xmpp_server.ports import ephemeral_range, free_port
from xmpp_server.process import ServerStartError
from xmpp_server.probe import LoginError, probe_login


async def test_embedded_server_hashes_passwords_with_fewer_rounds_and_reads_old_hashes(tmp_path):
    """New accounts are stored with PASSWORD_ROUNDS PBKDF2 iterations (login and registration cost
    ~1 ms, not ~35); an account stored with pyjabber's own 100 000 still logs in."""
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
        with pytest.raises(LoginError):
            await probe_login(server.host, server.port, server.domain, user="old", password="wrong", register=False)


async def test_chat_user_keeps_its_connection_past_the_servers_silence_timeout():
    """pyjabber drops a client silent for `connection_timeout` seconds and keeps the dropped
    connection listed as online; a message to the bare JID during the reconnection was lost (a
    hazard run waited forever for "finished"). The chat user's keep-alive pings prevent the drop."""
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


def test_a_server_dies_with_the_process_that_started_it():
    """A crashed `rapp run` or benchmark (SIGKILL, a native abort) leaves no server processes."""
    import os
    import subprocess
    import sys
    import time
    from pathlib import Path

    code = ("from xmpp_server.process import EmbeddedServer; import time; s = EmbeddedServer(); s.start(); "
            "print(s.proc.pid, flush=True); time.sleep(120)")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              cwd=Path(__file__).resolve().parents[1])
    group = os.getpgid(int(parent.stdout.readline()))

    def members() -> list[int]:
        found = []
        for d in filter(str.isdigit, os.listdir("/proc")):
            try:
                if int(Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()[2]) == group:
                    found.append(int(d))
            except (OSError, IndexError):
                pass
        return found

    assert members(), "the server runs"
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 10
    while members() and time.monotonic() < deadline:
        time.sleep(0.1)
    left = members()
    for pid in left:
        os.kill(pid, 9)
    assert not left, f"server processes outlived the process that started them: {left}"


def _hold(port: int):
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # the stopped server's TIME_WAITs
    s.bind(("127.0.0.1", port))
    s.listen()
    return s


async def test_a_restart_waits_for_its_port_and_a_taken_given_port_is_a_clear_error():
    """A restart on the old port that another listener holds a moment starts once it is free (CI
    saw pyjabber exit 0 with no message when its port was taken); held past the start timeout,
    the error names the port."""
    server = EmbeddedServer(start_timeout=20.0)
    await server.astart()
    port = server.port
    await asyncio.to_thread(server.stop)
    holder = _hold(port)
    loop = asyncio.get_running_loop()
    loop.call_later(1.0, holder.close)
    t0 = loop.time()
    await server.astart()
    try:
        assert server.port == port and loop.time() - t0 >= 0.9
        await probe_login(server.host, server.port, server.domain)
    finally:
        await asyncio.to_thread(server.close)
    holder = _hold(port)
    try:
        with pytest.raises(ServerStartError, match=f"port {port} .* in use"):
            await EmbeddedServer(port=port, start_timeout=1.0).astart()
    finally:
        holder.close()


def test_free_ports_lie_below_the_ephemeral_range_where_clients_take_theirs():
    low, _ = ephemeral_range()
    assert all(free_port() < low for _ in range(20))
