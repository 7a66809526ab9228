"""Private ejabberd nodes as child processes (not the system service), alone or as a cluster on
loopback: own config, Mnesia spool, certificate, log, Erlang node name, cookie and epmd.

    async with EjabberdCluster(nodes=2) as cluster:   # two nodes, one domain, one Mnesia database
        s1 = cluster.settings(0)                      # XmppSettings for node 1 (node 2 as fallback)
        cluster.nodes[1].kill()                       # a node fails; its clients use another one

Each node is `erl ... -s ejabberd` run in the foreground as the current user (root in CI). The
Debian `ejabberdctl` script switches to the `ejabberd` user when run as root and reads the system's
config and cookie, so the commands it offers (register, join_cluster, list_cluster, ...) are run
the way it runs them, `erl -hidden -s ejabberd_ctl -extra NODE COMMAND ARGS`, with this cluster's
cookie and epmd (`EjabberdNode.ctl`). The nodes' epmd is a child of ours on a free loopback port
(ERL_EPMD_PORT), so they never meet the system's Erlang nodes. Clients must use STARTTLS with a
self-signed certificate; settings() therefore has verify_tls=False. See docs/deployment.md.
"""
from __future__ import annotations

import asyncio
import contextlib
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from glob import glob
from pathlib import Path

from .ports import free_port
from .probe import LoginError, probe_login
from .process import ExternalServer, ManagedServer, ServerStartError, listening, terminate
from .prosody import make_self_signed_cert
from .settings import XmppSettings

ERLANG_HOST = "localhost"  # short node names: ejabberd1@localhost


class EjabberdCommandError(ServerStartError):
    """An ejabberdctl command failed (its output and the node's log tail are in the message)."""


def ejabberd_binary() -> str | None:
    """Path of `ejabberdctl` when ejabberd, Erlang (`erl`) and epmd are all installed, else None."""
    ctl = shutil.which("ejabberdctl") or next(iter(glob("/usr/sbin/ejabberdctl")), None)
    if not ctl or not shutil.which("erl") or not shutil.which("epmd") or not ejabberd_libs(ctl):
        return None
    return ctl


def ejabberd_libs(ctl: str | None = None) -> str | None:
    """ERL_LIBS holding ejabberd's code: what the installed ejabberdctl sets, else a search."""
    ctl = ctl or shutil.which("ejabberdctl")
    if ctl:
        m = re.search(r"^ERL_LIBS=['\"]?([^'\"\n]+)", Path(ctl).read_text(errors="replace"), re.M)
        if m and Path(m.group(1)).is_dir():
            return m.group(1)
    found = glob("/usr/lib/*/ejabberd-*/ebin/ejabberd.app") + glob("/usr/lib/ejabberd*/ebin/ejabberd.app")
    return str(Path(found[0]).parent.parent.parent) if found else None


def erlang_distribution_problem(timeout: float = 20.0) -> str | None:
    """Why Erlang nodes cannot be clustered on this machine (no loopback epmd, `localhost` not
    resolving, distribution failing to start), or None when a bare node starts its distribution
    with a private epmd. Tells the environment's problems from ejabberd's and ours."""
    try:
        if socket.gethostbyname(ERLANG_HOST) != "127.0.0.1":
            return f"{ERLANG_HOST} does not resolve to 127.0.0.1 (Erlang short node names need it)"
    except OSError as e:
        return f"{ERLANG_HOST} does not resolve: {e}"
    epmd = Epmd()
    try:
        epmd.start()
        node = f"probe-{secrets.token_hex(4)}@{ERLANG_HOST}"
        env = dict(os.environ, ERL_EPMD_PORT=str(epmd.port), ERL_EPMD_ADDRESS=epmd.host)
        res = subprocess.run([shutil.which("erl") or "erl", "-sname", node, "-setcookie", "probe",
                              "-start_epmd", "false", "-noinput", "-eval", "io:format(\"~s~n\", [node()]), halt()."],
                             capture_output=True, text=True, env=env, timeout=timeout)
        if res.returncode != 0 or node not in res.stdout:
            return f"an Erlang node cannot start its distribution: {(res.stdout + res.stderr).strip()[-500:]}"
        return None
    except (ServerStartError, OSError, subprocess.TimeoutExpired) as e:
        return str(e)
    finally:
        epmd.stop()




class Epmd:
    """Erlang's port mapper for one private cluster: a foreground child on a loopback port."""

    def __init__(self, port: int | None = None, host: str = "127.0.0.1"):
        self.host, self.port = host, port or free_port(host)
        self.proc: subprocess.Popen | None = None

    def start(self, timeout: float = 10.0) -> "Epmd":
        epmd = shutil.which("epmd")
        if not epmd:
            raise ServerStartError("epmd is not installed (it comes with erlang, apt-get install ejabberd)")
        env = dict(os.environ, ERL_EPMD_ADDRESS=self.host, ERL_EPMD_PORT=str(self.port))
        self.proc = subprocess.Popen([epmd, "-port", str(self.port)], env=env, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                     start_new_session=True)
        deadline = time.monotonic() + timeout
        while not listening(self.host, self.port):
            if self.proc.poll() is not None:
                err = self.proc.stderr.read().decode(errors="replace").strip()
                raise ServerStartError(f"epmd on {self.host}:{self.port} exited ({self.proc.returncode}): {err}")
            if time.monotonic() > deadline:
                self.stop()
                raise ServerStartError(f"epmd does not listen on {self.host}:{self.port} within {timeout:.0f}s")
            time.sleep(0.02)
        return self

    def stop(self) -> None:
        if self.proc is not None:
            terminate(self.proc, 3.0)
            self.proc.stderr.close()
            self.proc = None


class EjabberdNode(ExternalServer):
    """One private ejabberd node; same shape as ProsodyServer. Alone it starts its own epmd; in an
    EjabberdCluster the cluster gives it the shared cookie and epmd."""

    def __init__(self, name: str = "ejabberd1", host: str = "127.0.0.1", port: int | None = None,
                 domain: str = "localhost", workdir: str | Path | None = None, cookie: str | None = None,
                 epmd: Epmd | None = None, allow_registration: bool = True, verbose: bool = False,
                 start_timeout: float = 30.0):
        if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_-]*", name):
            raise ValueError(f"ejabberd node name {name!r}: letters, digits, '_' and '-' only")
        self.name, self.host, self.domain = name, host, domain
        self.port = port or free_port(host)
        self.node = f"{name}@{ERLANG_HOST}"
        self.cookie = cookie or secrets.token_hex(16)
        self.allow_registration, self.verbose, self.start_timeout = allow_registration, verbose, start_timeout
        self.ctl_path = ejabberd_binary()
        self._tmp = None if workdir else tempfile.TemporaryDirectory(prefix=f"rapp-{name}-")
        self.dir = Path(workdir or self._tmp.name)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.config_file = self.dir / "ejabberd.yml"
        self.log_file = self.dir / "ejabberd.log"
        self._epmd, self._own_epmd = epmd, epmd is None
        self.proc: subprocess.Popen | None = None
        self._out = None
        self.proc_rc: int | None = None

    # -- configuration ------------------------------------------------------------------------
    def config_text(self) -> str:
        register = "  mod_register: {access: register, access_remove: all, ip_access: all}\n" \
            if self.allow_registration else ""
        return f"""# private ejabberd node {self.node} for RAPP (written by xmpp_server/ejabberd.py)
hosts: [{_yaml(self.domain)}]
loglevel: {"debug" if self.verbose else "info"}
certfiles: [{_yaml(self.dir / "server.pem")}]
acme: {{auto: false}}

# client connections on loopback only, STARTTLS required; no s2s, no HTTP, no STUN/MQTT
listen:
  - port: {self.port}
    ip: {_yaml(self.host)}
    module: ejabberd_c2s
    starttls_required: true
    max_stanza_size: 1048576
    access: c2s
    # no shaper: the default example's 3000 B/s would throttle package downloads

auth_method: internal
auth_password_format: scram
# slixmpp offers channel binding that ejabberd refuses over TLS 1.3 ("Invalid channel binding"):
# each login would fail once with -PLUS before plain SCRAM
disable_sasl_mechanisms: ["digest-md5", "x-oauth2", "scram-sha-1-plus", "scram-sha-256-plus", "scram-sha-512-plus"]
registration_timeout: infinity   # default: one registration per IP address per 10 minutes

acl:
  loopback: {{ip: ["127.0.0.0/8", "::1/128"]}}
access_rules:
  c2s: {{allow: all}}
  register: {{allow: all}}
api_permissions:
  "console commands": {{from: [ejabberd_ctl], who: all, what: "*"}}
shaper_rules:
  max_user_sessions: 10

modules:
  mod_admin_extra: {{}}   # ejabberdctl connected_users_info (which node serves whom)
  mod_disco: {{}}
  mod_ping: {{}}
  mod_roster: {{}}
  mod_time: {{}}
  mod_version: {{}}
{register}"""

    def write_config(self) -> Path:
        (self.dir / "spool").mkdir(exist_ok=True)
        pem = self.dir / "server.pem"
        if not pem.exists():
            cert, key = self.dir / "server.crt", self.dir / "server.key"
            make_self_signed_cert(self.domain, cert, key)
            pem.write_bytes(cert.read_bytes() + key.read_bytes())
            pem.chmod(0o600)
        self.config_file.write_text(self.config_text())
        return self.config_file

    def _erl_env(self) -> dict[str, str]:
        if self._epmd is None:
            raise RuntimeError(f"ejabberd node {self.node} was never started (no epmd yet)")
        return dict(os.environ, HOME=str(self.dir), ERL_LIBS=ejabberd_libs(self.ctl_path) or "",
                    ERL_EPMD_PORT=str(self._epmd.port), ERL_EPMD_ADDRESS=self._epmd.host,
                    ERL_CRASH_DUMP=str(self.dir / "erl_crash.dump"), ERL_CRASH_DUMP_BYTES="0",
                    EJABBERD_CONFIG_PATH=str(self.config_file), EJABBERD_LOG_PATH=str(self.log_file))

    def _erl_args(self, node: str) -> list[str]:
        """The VM arguments every process of this cluster needs: its node name, the cookie, the
        distribution on loopback only, the private epmd (never start another)."""
        return [shutil.which("erl") or "erl", "-sname", node, "-setcookie", self.cookie,
                "-kernel", "inet_dist_use_interface", "{127,0,0,1}", "-start_epmd", "false"]

    def command(self) -> list[str]:
        return [*self._erl_args(self.node), "-noinput", "-mnesia", "dir", f'"{self.dir / "spool"}"',
                "-s", "ejabberd"]

    def ctl(self, *args: str, check: bool = True, timeout: float = 60.0) -> subprocess.CompletedProcess:
        """An `ejabberdctl` command on this node (e.g. register USER DOMAIN PASSWORD, join_cluster
        NODE, list_cluster), run as `ejabberdctl` runs it but with this node's cookie and epmd.
        EjabberdCommandError with the command's output and the node's log tail when it fails."""
        node = f"ctl-{secrets.token_hex(4)}@{ERLANG_HOST}"
        cmd = [*self._erl_args(node), "-hidden", "-noinput", "-s", "ejabberd_ctl", "-extra", self.node, *args]
        res = subprocess.run(cmd, capture_output=True, text=True, env=self._erl_env(), cwd=self.dir,
                             timeout=timeout)
        if check and res.returncode != 0:
            out = (res.stdout + res.stderr).strip()[-1000:]
            raise EjabberdCommandError(f"ejabberdctl {' '.join(args[:1])} on {self.node} failed "
                                       f"({res.returncode}): {out}; {self.diagnostics()}")
        return res

    def register(self, user: str, password: str) -> None:
        """Create an account without in-band registration (the node must be running)."""
        self.ctl("register", user, self.domain, password)

    def join_cluster(self, other: "EjabberdNode | str") -> None:
        """Make this node a member of `other`'s cluster. ejabberd restarts here with `other`'s
        Mnesia database (this node's own accounts are dropped); the c2s port closes meanwhile."""
        self.ctl("join_cluster", other if isinstance(other, str) else other.node, timeout=120)

    def cluster_nodes(self) -> list[str]:
        """The running nodes of this node's cluster (`ejabberdctl list_cluster`)."""
        out = self.ctl("list_cluster").stdout
        return sorted(re.findall(r"'?([A-Za-z0-9_-]+@[A-Za-z0-9_.-]+)'?", out))

    def sessions(self) -> dict[str, str]:
        """Every client session of the cluster: bare JID -> the node serving it
        (`ejabberdctl connected_users_info`; one entry per account, the last session listed)."""
        out = {}
        for line in self.ctl("connected_users_info").stdout.splitlines():
            cols = line.split("\t")
            if len(cols) > 5:
                out[cols[0].split("/")[0]] = cols[5]
        return out

    # -- lifecycle ----------------------------------------------------------------------------
    def _spawn(self) -> None:
        if not self.ctl_path:
            raise ServerStartError("ejabberd is not installed (apt-get install ejabberd)")
        if self._epmd is None:
            self._epmd = Epmd()
        if self._own_epmd and self._epmd.proc is None:
            self._epmd.start()
        self.write_config()
        self._out = open(self.dir / "erl.out", "w")
        self.proc = subprocess.Popen(self.command(), stdin=subprocess.DEVNULL, stdout=self._out,
                                     stderr=subprocess.STDOUT, env=self._erl_env(), cwd=self.dir,
                                     start_new_session=True)

    async def astart(self) -> "EjabberdNode":
        await asyncio.to_thread(self._spawn)
        await self.wait_ready()
        return self

    async def wait_ready(self, timeout: float | None = None) -> None:
        """Until a client can log in (in-band registration) or at least connect; ServerStartError
        with the log tail when the node exits or does not get there in time."""
        deadline = time.monotonic() + (timeout or self.start_timeout)
        last: Exception | None = None
        while time.monotonic() < deadline:
            if self.proc is None or self.proc.poll() is not None:
                why = self.diagnostics()
                rc = None if self.proc is None else self.proc.returncode
                self.stop()
                raise ServerStartError(f"ejabberd node {self.node} exited ({rc}) at start: {why}")
            if not await asyncio.to_thread(listening, self.host, self.port):
                await asyncio.sleep(0.1)
                continue
            if not self.allow_registration:
                return
            try:
                await probe_login(self.host, self.port, self.domain,
                                  timeout=min(3.0, max(0.5, deadline - time.monotonic())))
                return
            except LoginError as e:
                last = e
            await asyncio.sleep(0.1)
        why = self.diagnostics()
        self.stop()
        raise ServerStartError(f"ejabberd node {self.node} on {self.host}:{self.port} accepts no login "
                               f"within {timeout or self.start_timeout:.0f}s: {last}; {why}")

    def diagnostics(self, tail: int = 1200) -> str:
        """The log's first error and critical lines (the cause; the reports after them are long),
        then the tail of the VM's output."""
        out = []
        if self.log_file.exists():
            firsts = [line[:300] for line in self.log_file.read_text(errors="replace").splitlines()
                      if "[error]" in line or "[critical]" in line][:3]
            if firsts:
                out.append("ejabberd.log: " + " / ".join(firsts))
        f = self.dir / "erl.out"
        if f.exists() and (text := f.read_text(errors="replace").strip()):
            out.append(f"erl.out: ...{text[-tail:]}")
        return " | ".join(out) or "no output"

    def kill(self) -> None:
        """The node fails at once (SIGKILL to its VM, no orderly shutdown): the kernel resets its
        clients' connections; the other nodes see it go down."""
        if self.proc is not None and self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.proc.pid, signal.SIGKILL)
        self.stop()

    def stop(self, timeout: float = 15.0) -> None:
        """SIGTERM (the VM shuts down in order), SIGKILL after `timeout`; then the own epmd."""
        if self.proc is not None:
            self.proc_rc = terminate(self.proc, timeout)
            self.proc = None
        if self._out:
            self._out.close()
            self._out = None
        if self._own_epmd and self._epmd is not None:
            self._epmd.stop()


class EjabberdCluster(ManagedServer):
    """`nodes` ejabberd nodes on loopback (ejabberd1@localhost, ...), one domain, one cookie, one
    private epmd; nodes 2.. join node 1's cluster, so they share accounts, rosters and sessions."""

    def __init__(self, nodes: int = 2, domain: str = "localhost", host: str = "127.0.0.1",
                 workdir: str | Path | None = None, start_timeout: float = 60.0, verbose: bool = False):
        if nodes < 1:
            raise ValueError("an ejabberd cluster needs at least one node")
        self._tmp = None if workdir else tempfile.TemporaryDirectory(prefix="rapp-ejabberd-")
        self.dir = Path(workdir or self._tmp.name)
        self.epmd = Epmd(host=host)
        self.cookie = secrets.token_hex(16)
        self.start_timeout = start_timeout
        self.nodes = [EjabberdNode(f"ejabberd{i + 1}", host=host, domain=domain, workdir=self.dir / f"node{i + 1}",
                                   cookie=self.cookie, epmd=self.epmd, verbose=verbose,
                                   start_timeout=start_timeout) for i in range(nodes)]
        self.domain = domain

    def settings(self, index: int, **overrides) -> XmppSettings:
        """Settings for clients of node `index`; the other nodes are their fallback addresses."""
        others = [f"{n.host}:{n.port}" for i, n in enumerate(self.nodes) if i != index]
        return self.nodes[index].settings(fallback=others, **overrides)

    async def astart(self) -> "EjabberdCluster":
        try:
            await asyncio.to_thread(self.epmd.start)
            # the nodes boot side by side; then each joins the first (one at a time: a join
            # restarts the joining node's ejabberd on the first node's database)
            await asyncio.gather(*(n.astart() for n in self.nodes))
            first = self.nodes[0]
            for node in self.nodes[1:]:
                await asyncio.to_thread(node.join_cluster, first)
                await node.wait_ready()
            members = await asyncio.to_thread(first.cluster_nodes)
            expected = sorted(n.node for n in self.nodes)
            if members != expected:
                raise ServerStartError(f"ejabberd cluster has {members}, expected {expected}; "
                                       f"{self.nodes[-1].diagnostics()}")
        except BaseException:
            await asyncio.to_thread(self.stop)
            raise
        return self

    def running(self) -> bool:
        return bool(self.nodes) and all(node.running() for node in self.nodes)

    def stop(self) -> None:
        threads = [threading.Thread(target=node.stop) for node in self.nodes]  # ~1 s each, in parallel
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        self.epmd.stop()

    def close(self) -> None:
        self.stop()
        for node in self.nodes:
            node.close()
        super().close()


def _yaml(value) -> str:
    """A double-quoted YAML scalar."""
    return '"' + str(value).replace("\\", "\\\\").replace('"', '\\"') + '"'
