"""Hand-off latency: from the user's command arriving at the Core (its `command` structure record)
to the Dynamic Agent's first behaviour running (its first FSM `state` enter record), i.e. download,
verify, unpack, spawn, login and Init included. Measured from the trace.

Three ways of starting the Dynamic Agent, in one system (one server, Store, Platform and Core):
- `handoff`: the Core's default, a sandboxed process through a warm worker (agents/warm_pool.py:
  started ahead of time, runtime imported, waiting for its spec). Floor: the in-process hand-off of
  the same run (the same package bytes, download, unpack and runtime code, as a task of the Core: no
  isolation at all); the two alternate (warm, in-process, warm, ...) so machine noise hits both
  alike. Before each measured hand-off the pool's worker has finished its imports and the last
  run's clean-up (logouts, account deletions) had SETTLE_S: a user's next command comes seconds
  after the last, the refill takes about one.
- `handoff_inprocess`: that floor, with its own absolute goal (issue #8).
- `handoff_cold` (context): a process started at the hand-off (the pool closed, the cost of an
  interpreter start and SPADE import), against a bare Python process that imports SPADE and logs
  one new agent in (bench/floor_login.py), alternating.

Each also reports command -> the robot's first command, the first robot-API request of the RApp
(the echo RApp's `say`, it does not drive) as the Core received it: what the user notices first.
"""
from __future__ import annotations

import asyncio
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ontology.trace import RecordKind

from .common import ECHO_APP, RobotSystem, child_env, log, median, metric, percentile, ratio

GOAL_MS = 100.0  # issue #20: the process-isolated hand-off, absolute, on this machine
GOAL_RATIO = 3.0  # issue #20: ... and against the in-process hand-off of the same run
INPROCESS_GOAL_MS = 100.0  # issue #8: the in-process hand-off, absolute, on this machine
ECHO_DONE = "echo-app finished"
SETTLE_S = 0.5  # before each command: what the last run left to do (logouts, deletions) is done


def floor_once(settings, name: str) -> float:
    t0 = time.time()
    out = subprocess.run([sys.executable, "-m", "bench.floor_login", name], env=child_env(settings),
                         capture_output=True, text=True, timeout=60)
    line = next((ln for ln in out.stdout.splitlines() if ln.startswith("LOGGED_IN")), None)
    if line is None:
        raise RuntimeError(f"floor_login failed: {out.stderr[-500:]}")
    return float(line.split()[1]) - t0


def phases(trace: list[dict]) -> list[dict]:
    """Per hand-off: command, download, spawn, dyn started, first state and first robot command
    times (absolute), and how it was spawned (`mode`: warm, cold or inprocess)."""
    out = []
    structure = [r for r in trace if r["kind"] == RecordKind.STRUCTURE]
    for sp in (r for r in structure if r["event"] == "spawn"):
        dyn = sp["dynamic"]
        cmd = [r for r in structure if r["event"] == "command" and r["agent"] == sp["agent"] and r["t"] <= sp["t"]]
        dl = [r for r in structure if r["event"] == "download" and r["agent"] == sp["agent"] and r["t"] <= sp["t"]]
        started = [r for r in trace if r["kind"] == RecordKind.AGENT and r["event"] == "started" and r["agent"] == dyn]
        state = [r for r in trace if r["kind"] == RecordKind.STATE and r["event"] == "enter" and r["agent"] == dyn]
        robot = [r for r in trace if r["kind"] == RecordKind.MESSAGE and r["dir"] == "recv" and r["ontology"] == "robot"
                 and r["agent"] == sp["agent"] and r["sender"] == dyn and r["performative"] == "request"]
        if not (cmd and state):
            continue
        mode = "inprocess" if sp["pid"] == os.getpid() else "warm" if sp.get("warm") else "cold"
        out.append({"command": cmd[-1]["t"], "download": dl[-1]["t"] if dl else None, "spawn": sp["t"],
                    "started": started[0]["t"] if started else None, "state": state[0]["t"],
                    "robot": robot[0]["t"] if robot else None, "mode": mode, "pid": sp["pid"]})
    return out


def phase_medians(ph: list[dict]) -> dict:
    extra = {}
    for a, b, key in (("command", "download", "cmd_to_download_ms"), ("download", "spawn", "download_to_spawn_ms"),
                      ("spawn", "started", "spawn_to_login_ms"), ("started", "state", "login_to_first_state_ms"),
                      ("command", "robot", "cmd_to_first_robot_command_ms")):
        xs = [p[b] - p[a] for p in ph if p[a] is not None and p[b] is not None]
        if xs:
            extra[key] = median(xs) * 1e3
    return extra


class Handoffs:
    """Hand-offs of the echo app on one robot, the spawning mode chosen per hand-off; the phases
    are read from the trace at the end, in command order."""

    def __init__(self, rs: RobotSystem):
        self.rs, self.handle = rs, rs.robots[0]
        self.core = self.handle.core
        self.kinds: list[str] = []  # per command: the label it is measured under ("warm-up" is not)
        self.pooled = True

    async def once(self, label: str, mode: str) -> None:
        self.core.dynamic_mode = mode
        if self.pooled:  # a warm worker waits, and no refill competes for the CPU
            await self.core.warm_pool.wait_ready()
        await asyncio.sleep(SETTLE_S)
        await self.rs.command(self.handle, "echo", ECHO_DONE)
        self.kinds.append(label)

    async def close_pool(self) -> None:
        """From here on every process starts at the hand-off."""
        await self.core.warm_pool.close()
        self.pooled = False

    def measured(self) -> dict[str, list[dict]]:
        from agents.tracing import read_trace

        ph = phases(read_trace(self.rs.trace_file))
        if len(ph) != len(self.kinds):
            raise RuntimeError(f"expected {len(self.kinds)} hand-offs in the trace, found {len(ph)}")
        out: dict[str, list[dict]] = {}
        for kind, p in zip(self.kinds, ph):
            out.setdefault(kind, []).append(p)
        return out


async def measure(n: int) -> tuple[dict[str, list[dict]], list[float]]:
    floors: list[float] = []
    with tempfile.TemporaryDirectory(prefix="bench-handoff-") as tmp:
        async with RobotSystem(Path(tmp), [ECHO_APP], trace=True) as rs:
            h = Handoffs(rs)
            await h.once("warm-up", "process")  # first imports from a cold page cache
            await h.once("warm-up", "inprocess")
            for _ in range(n):  # alternating: noise hits both alike
                await h.once("warm", "process")
                await h.once("inprocess", "inprocess")
            await h.close_pool()
            for i in range(n):
                await h.once("cold", "process")
                floors.append(await asyncio.to_thread(floor_once, rs.system.settings, f"floor-{i}"))
            measured = h.measured()
    measured.pop("warm-up")
    for label, expected in (("warm", "warm"), ("inprocess", "inprocess"), ("cold", "cold")):
        modes = {p["mode"] for p in measured[label]}
        if modes != {expected}:  # e.g. a worker not ready: the hand-off started cold
            raise RuntimeError(f"{label} hand-offs were spawned as {sorted(modes)}")
    return measured, floors


# what the sandbox's own start costs (agents/confine.py: namespaces, root, control group, filter, the
# XMPP forwarding), with nothing else: a process that confines itself and connects once to a listener
# standing for the server, against the same process unsandboxed (mode "off"), alternating
SANDBOX_PROBE = (
    "import os, socket, sys, time\n"
    "from agents.sandbox import confine\n"
    "confine()\n"
    "t = time.time()\n"
    "s = socket.create_connection((os.environ['RAPP_XMPP_HOST'], int(os.environ['RAPP_XMPP_PORT'])))\n"
    "s.sendall(b'x'); s.recv(1)\n"
    "print(t, time.time() - t, flush=True)\n")


async def measure_sandbox(n: int) -> tuple[str, dict[str, list[float]]]:
    """(the sandbox's mode, {mode: [ms from Popen to confined], "connect_<mode>": [ms of a connection
    and one round trip to the server]}): what confinement and the forwarding add to a cold start."""
    from agents.process import AgentProcess
    from agents.sandbox import Sandbox, probe
    from ontology.spawn import SpawnSpec
    from xmpp_server.settings import XmppSettings

    mode = probe().mode
    if mode == "off":
        return mode, {}
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(64)
    server.setblocking(False)
    loop = asyncio.get_running_loop()

    async def echo():
        while True:
            conn, _ = await loop.sock_accept(server)
            loop.create_task(_echo_once(loop, conn))

    echoer = loop.create_task(echo())
    settings = XmppSettings(host="127.0.0.1", port=server.getsockname()[1])
    out: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="rapp-bench-sandbox-") as tmp:
        for i in range(n):
            for m in (mode, "off"):
                work = Path(tmp) / f"{i:03d}-{m}"
                (work / "package").mkdir(parents=True)
                spec = SpawnSpec(kind="dynamic", name="dyn-bench", password="x", package_dir="",
                                 core="core@localhost", platform="platform@localhost", token="t")
                proc = AgentProcess("bench", spec, work, settings, sandbox=Sandbox(mode=m))
                proc.argv = [sys.executable, "-P", "-c", SANDBOX_PROBE]
                t0 = time.time()
                await proc.start()
                await proc.wait()
                line = (work / "stdout.log").read_text().split()
                if len(line) == 2:
                    out.setdefault(m, []).append((float(line[0]) - t0) * 1e3)
                    out.setdefault(f"connect_{m}", []).append(float(line[1]) * 1e3)
    echoer.cancel()
    server.close()
    return mode, out


async def _echo_once(loop, conn) -> None:
    try:
        data = await loop.sock_recv(conn, 16)
        await loop.sock_sendall(conn, data)
    except OSError:
        pass
    conn.close()


def totals_ms(ph: list[dict]) -> list[float]:
    return [(p["state"] - p["command"]) * 1e3 for p in ph]


async def run(quick: bool = True, n: int | None = None) -> list[dict]:
    n = n or (3 if quick else 10)
    measured, floors = await measure(n)
    warm, inproc, cold = (totals_ms(measured[k]) for k in ("warm", "inprocess", "cold"))
    wmed, imed, cmed, fmed = median(warm), median(inproc), median(cold), median(floors) * 1e3
    wx, ix, cx = (phase_medians(measured[k]) for k in ("warm", "inprocess", "cold"))
    log(f"handoff (warm worker) median {wmed:.1f} ms, in-process {imed:.1f} ms (ratio {wmed / imed:.2f}, "
        f"goal <= {GOAL_MS:.0f} ms and <= {GOAL_RATIO:g}x); phases {wx}")
    log(f"handoff_inprocess median {imed:.1f} ms (goal <= {INPROCESS_GOAL_MS:.0f} ms); phases {ix}")
    log(f"handoff_cold median {cmed:.0f} ms, floor (python + SPADE + login) {fmed:.0f} ms; phases {cx}")
    mode, box = await measure_sandbox(n)
    extra = []
    if box.get(mode) and box.get("off"):
        smed, omed = median(box[mode]), median(box["off"])
        cs, co = median(box[f"connect_{mode}"]), median(box["connect_off"])
        log(f"sandbox_start ({mode}) median {smed:.1f} ms from Popen to confined, unsandboxed {omed:.1f} ms; "
            f"a connection and one round trip to the server {cs:.2f} ms through the sandbox, {co:.2f} ms without")
        extra = [metric("sandbox_start", smed, "ms", omed, ratio(smed, omed), n, samples=box[mode], mode=mode,
                        connect_ms=cs, connect_unsandboxed_ms=co, samples_unsandboxed=box["off"],
                        note="context: a cold start's confinement (warm workers pay it ahead of the hand-off)")]
    return extra + [metric("handoff", wmed, "ms", imed, ratio(wmed, imed), n, samples=warm, goal_ratio=GOAL_RATIO,
                   goal_ms=GOAL_MS, floor_is="in-process hand-off, same run", **wx),
            metric("handoff_inprocess", imed, "ms", INPROCESS_GOAL_MS, ratio(imed, INPROCESS_GOAL_MS), n,
                   samples=inproc, goal_ratio=1.0, **ix),
            metric("handoff_cold", cmed, "ms", fmed, ratio(cmed, fmed), n, samples=cold,
                   floor_p95=percentile(floors, 95) * 1e3,
                   note="context: no warm worker; floor = python + SPADE import + one login", **cx)]
