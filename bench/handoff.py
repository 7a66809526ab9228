"""Hand-off latency: from the user's command arriving at the Core (its `command` structure record)
to the Dynamic Agent's first behaviour running (its first FSM `state` enter record), i.e. download,
verify, unpack, spawn, interpreter start, login and Init included. Measured from the trace.

Floor, in the same run and against the same server: spawning a bare Python process that imports
SPADE and logs one new agent in (bench/floor_login.py), from Popen to the child's printed time.
Runs alternate (project, floor, project, floor, ...) so machine noise hits both alike.
"""
from __future__ import annotations

import asyncio
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ontology.trace import RecordKind

from .common import ECHO_APP, RobotSystem, child_env, log, median, metric, percentile, ratio


def floor_once(settings, name: str) -> float:
    t0 = time.time()
    out = subprocess.run([sys.executable, "-m", "bench.floor_login", name], env=child_env(settings),
                         capture_output=True, text=True, timeout=60)
    line = next((ln for ln in out.stdout.splitlines() if ln.startswith("LOGGED_IN")), None)
    if line is None:
        raise RuntimeError(f"floor_login failed: {out.stderr[-500:]}")
    return float(line.split()[1]) - t0


def phases(trace: list[dict]) -> list[dict]:
    """Per hand-off: command, download, spawn, dyn started, first state times (absolute)."""
    out = []
    spawns = [r for r in trace if r["kind"] == RecordKind.STRUCTURE and r["event"] == "spawn"]
    for sp in spawns:
        dyn = sp["dynamic"]
        cmd = [r for r in trace if r["kind"] == RecordKind.STRUCTURE and r["event"] == "command"
               and r["agent"] == sp["agent"] and r["t"] <= sp["t"]]
        dl = [r for r in trace if r["kind"] == RecordKind.STRUCTURE and r["event"] == "download"
              and r["agent"] == sp["agent"] and r["t"] <= sp["t"]]
        started = [r for r in trace if r["kind"] == RecordKind.AGENT and r["event"] == "started" and r["agent"] == dyn]
        state = [r for r in trace if r["kind"] == RecordKind.STATE and r["event"] == "enter" and r["agent"] == dyn]
        if not (cmd and state):
            continue
        out.append({"command": cmd[-1]["t"], "download": dl[-1]["t"] if dl else None, "spawn": sp["t"],
                    "started": started[0]["t"] if started else None, "state": state[0]["t"]})
    return out


INPROCESS_GOAL_MS = 100.0  # issue #8: the in-process hand-off, absolute, on this machine


async def inprocess(n: int) -> dict:
    """The same hand-off with the Core's in-process mode (same package bytes, no interpreter start):
    an absolute goal, reported with the goal as its floor."""
    with tempfile.TemporaryDirectory(prefix="bench-handoff-inproc-") as tmp:
        async with RobotSystem(Path(tmp), [ECHO_APP], trace=True, dynamic_mode="inprocess") as rs:
            ph = await measured_handoffs(rs, n)
    total = [(p["state"] - p["command"]) * 1e3 for p in ph]
    med, extra = median(total), phase_medians(ph)
    log(f"handoff_inprocess median {med:.1f} ms (goal <= {INPROCESS_GOAL_MS:.0f} ms); phases {extra}")
    return metric("handoff_inprocess", med, "ms", INPROCESS_GOAL_MS, ratio(med, INPROCESS_GOAL_MS), n,
                  samples=total, goal_ratio=1.0, **extra)


def phase_medians(ph: list[dict]) -> dict:
    extra = {}
    for a, b, key in (("command", "download", "cmd_to_download_ms"), ("download", "spawn", "download_to_spawn_ms"),
                      ("spawn", "started", "spawn_to_login_ms"), ("started", "state", "login_to_first_state_ms")):
        xs = [p[b] - p[a] for p in ph if p[a] is not None and p[b] is not None]
        if xs:
            extra[key] = median(xs) * 1e3
    return extra


async def measured_handoffs(rs: RobotSystem, n: int, between=None) -> list[dict]:
    """Phases of n hand-offs of the echo app after one warm-up hand-off (first imports from a cold
    page cache), read from the trace; `between(i)` (a coroutine function) runs after each one."""
    from agents.tracing import read_trace

    h = rs.robots[0]
    await rs.command(h, "echo", "echo-app finished")
    if between is not None:
        await between("warm")
    skip = len(phases(read_trace(rs.trace_file)))
    for i in range(n):
        await rs.command(h, "echo", "echo-app finished")
        if between is not None:
            await between(i)
    ph = phases(read_trace(rs.trace_file))[skip:]
    if len(ph) != n:
        raise RuntimeError(f"expected {n} hand-offs in the trace, found {len(ph)}")
    return ph


async def run(quick: bool = True, n: int | None = None) -> list[dict]:
    n = n or (3 if quick else 10)
    floors = []
    with tempfile.TemporaryDirectory(prefix="bench-handoff-") as tmp:
        async with RobotSystem(Path(tmp), [ECHO_APP], trace=True) as rs:
            async def floor(i) -> None:  # alternating with the hand-offs: noise hits both alike
                t = await asyncio.to_thread(floor_once, rs.system.settings, f"floor-{i}")
                if i != "warm":
                    floors.append(t)

            ph = await measured_handoffs(rs, n, between=floor)
    total = [p["state"] - p["command"] for p in ph]
    med, fmed = median(total), median(floors)
    extra = phase_medians(ph)
    log(f"handoff median {med * 1e3:.0f} ms, floor {fmed * 1e3:.0f} ms; phases {extra}")
    return [metric("handoff", med * 1e3, "ms", fmed * 1e3, ratio(med, fmed), n,
                   samples=[x * 1e3 for x in total], floor_p95=percentile(floors, 95) * 1e3,
                   goal_ratio=1.5, **extra),
            await inprocess(n)]
