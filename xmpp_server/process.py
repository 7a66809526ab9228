"""The embedded XMPP server as a child process: start on free ports, wait for a real login, stop.

    with EmbeddedServer() as srv:          # or: async with / await srv.astart()
        settings = srv.settings()          # XmppSettings pointing at it

The database is a fresh SQLite file per run (pyjabber's in-memory database is wiped when a client
disconnects mid-query), so it lives in a temporary directory unless `db` is given.
"""
from __future__ import annotations

import asyncio
import functools
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .ports import EXIT_PORT_IN_USE, free_port
from .probe import LoginError, probe_login
from .settings import XmppSettings


class ServerStartError(RuntimeError):
    pass


@functools.lru_cache(maxsize=1)
def libc():
    """The C library (errno kept), looked up once (find_library runs ldconfig); None without one."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    return ctypes.CDLL(name, use_errno=True) if name else None


PR_SET_PDEATHSIG = 1


def dies_with_parent():
    """A Popen preexec_fn: the child gets SIGTERM when the thread that started it ends (Linux's
    parent-death signal; start it from a thread that lives as long as the parent, e.g. the event
    loop's), so a crashed run or benchmark leaves no server or agent process behind. None where
    libc or prctl is missing. libc is looked up here: the child only calls it."""
    lib = libc() if sys.platform.startswith("linux") else None
    prctl = getattr(lib, "prctl", None)
    if prctl is None:
        return None
    parent = os.getpid()

    def arm() -> None:
        prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        if os.getppid() != parent:  # the parent died before it was armed
            os._exit(1)

    return arm


def terminate(proc: subprocess.Popen, timeout: float) -> int:
    """SIGTERM, then SIGKILL after `timeout`, to the server's whole process group (pyjabber forks
    a worker pool that inherits the listening socket: left alone, a killed server's worker kept
    the port and lived on as an orphan); always waits (no zombie)."""
    if proc.poll() is None:
        signal_group(proc, signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            signal_group(proc, signal.SIGKILL)
            proc.wait()
    signal_group(proc, signal.SIGKILL)  # workers of a server that died first
    return proc.returncode


def signal_group(proc: subprocess.Popen, sig: int) -> None:
    """`sig` to the process group `proc` leads (started with start_new_session); none left: nothing."""
    try:
        os.killpg(proc.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


class ManagedServer:
    """Plumbing shared by the server wrappers: subclasses provide `astart()`, `stop()`, a temporary
    directory in `_tmp` (or None) and, when they run one process, `proc`."""

    _tmp = None
    proc = None

    def start(self):
        """`astart()` from synchronous code (not inside an event loop: there, await astart())."""
        if _loop_running():
            raise RuntimeError(f"{type(self).__name__}.start() inside an event loop: use `await astart()`")
        return asyncio.run(self.astart())

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def close(self) -> None:
        self.stop()
        if self._tmp:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()

    async def __aenter__(self):
        return await self.astart()

    async def __aexit__(self, *exc):
        await asyncio.to_thread(self.close)


class ExternalServer(ManagedServer):
    """A server binary of the system (Prosody, ejabberd) run privately: what its wrappers share."""

    host: str
    port: int
    domain: str
    allow_registration: bool

    def settings(self, **overrides) -> XmppSettings:
        """Agent settings for this server (self-signed TLS: not verified); None overrides are ignored."""
        base = {"host": self.host, "port": self.port, "domain": self.domain, "verify_tls": False,
                "auto_register": self.allow_registration}
        base.update({k: v for k, v in overrides.items() if v is not None})
        return XmppSettings.from_env(**base)


def listening(host: str, port: int) -> bool:
    """Something accepts TCP connections at host:port."""
    try:
        with socket.create_connection((host, port), timeout=0.5):
            return True
    except OSError:
        return False


class EmbeddedServer(ManagedServer):
    def __init__(self, host: str = "127.0.0.1", port: int | None = None, domain: str = "localhost",
                 db: str | Path | None = None, memory: bool = False, verbose: bool = False,
                 start_timeout: float = 20.0, connection_timeout: int | None = None,
                 trace_file: str | Path | None = None):
        self.host = host
        self.port = port or free_port(host)
        self.port_chosen = port is None  # ours to change until the server first listens
        self.domain = domain
        self.memory = memory
        self._tmp = None if (db or memory) else tempfile.TemporaryDirectory(prefix="rapp-xmpp-")
        self.db = None if memory else str(db or Path(self._tmp.name) / "server.db")
        self.verbose = verbose
        self.start_timeout = start_timeout
        self.connection_timeout = connection_timeout  # None: the server's default
        self.proc: subprocess.Popen | None = None
        self.trace_file = trace_file  # failed logins and in-band registrations are traced there

    def command(self) -> list[str]:
        cmd = [sys.executable, "-m", "xmpp_server", "--host", self.host, "--port", str(self.port),
               "--domain", self.domain]
        if self.db:
            cmd += ["--db", self.db]
        if self.connection_timeout is not None:
            cmd += ["--connection-timeout", str(self.connection_timeout)]
        if self.trace_file:
            cmd += ["--trace", str(self.trace_file)]
        if self.verbose:
            cmd.append("--verbose")
        return cmd

    def settings(self, **overrides) -> XmppSettings:
        return XmppSettings.from_env(host=self.host, port=self.port, domain=self.domain, **overrides)

    # -- lifecycle -------------------------------------------------------------------------
    def _spawn(self) -> None:
        env = dict(os.environ)
        root = str(Path(__file__).resolve().parent.parent)
        env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
        self.proc = subprocess.Popen(self.command(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, env=env, start_new_session=True, preexec_fn=dies_with_parent())

    async def astart(self) -> "EmbeddedServer":
        """Start and wait for a real login. A port found in use is retried until the deadline (a
        restart on the old port: another listener may hold it a moment) or, at a first start on a
        port this object chose, replaced by another free one."""
        deadline = time.monotonic() + self.start_timeout
        await asyncio.to_thread(libc)  # looked up once (ldconfig) off the loop; the fork stays on the loop's
        while True:  # thread: the parent-death signal follows the thread that forked (dies_with_parent)
            self._spawn()
            line = await asyncio.to_thread(self._read_ready_line, deadline)
            if line.startswith("READY"):
                self.port_chosen = False  # clients know it now: a restart keeps it
                break
            in_use = self.proc.poll() == EXIT_PORT_IN_USE
            await asyncio.to_thread(self.stop)
            if not in_use or time.monotonic() > deadline:
                raise ServerStartError(f"embedded XMPP server did not start: {line}")
            if self.port_chosen:
                self.port = free_port(self.host)
            else:
                await asyncio.sleep(0.2)
        last: Exception | None = None
        while time.monotonic() < deadline:
            try:
                await probe_login(self.host, self.port, self.domain, timeout=min(2.0, max(0.5, deadline - time.monotonic())))
                return self
            except LoginError as e:
                last = e
                await asyncio.sleep(0.05)
        await asyncio.to_thread(self.stop)  # waits for the process: not on the loop
        raise ServerStartError(f"embedded XMPP server on {self.host}:{self.port} accepts no login: {last}")

    def _read_ready_line(self, deadline: float) -> str:
        assert self.proc and self.proc.stdout
        line = self.proc.stdout.readline().strip()  # the child prints READY once listening
        if not line:  # its output closed: it is exiting (not necessarily reaped yet)
            try:
                self.proc.wait(max(0.5, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                return "its output closed but it did not exit"
            return f"process exited ({self.proc.returncode}): {self.proc.stderr.read().strip()[-2000:]}"
        return line

    def stop(self, timeout: float = 5.0) -> None:
        if self.proc is None:
            return
        terminate(self.proc, timeout)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream:
                stream.close()
        self.proc = None


def _loop_running() -> bool:
    try:
        asyncio.get_running_loop()
        return True
    except RuntimeError:
        return False

