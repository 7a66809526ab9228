"""Shared helpers of the benchmarks: statistics, metric records, the result table.

A metric is a dict with at least: name, value, unit, floor, ratio, n; plus median and p95 where the
value is a distribution, and free extra fields (length_ratio, goal, note, ...).
"""
from __future__ import annotations

import asyncio
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterable

ROOT = Path(__file__).resolve().parent.parent
ECHO_APP = ROOT / "tests" / "fixtures" / "echo_app"
RTT_PROBE = Path(__file__).resolve().parent / "rapps" / "rtt_probe"


def percentile(xs: Iterable[float], q: float) -> float:
    """Linear-interpolated percentile (numpy's default method) without numpy."""
    a = sorted(xs)
    if not a:
        return float("nan")
    k = (len(a) - 1) * q / 100.0
    lo, hi = math.floor(k), math.ceil(k)
    return a[lo] + (a[hi] - a[lo]) * (k - lo)


def median(xs: Iterable[float]) -> float:
    return percentile(xs, 50)


def _r(x: Any, nd: int = 4):
    if isinstance(x, float):
        if math.isnan(x) or math.isinf(x):
            return None
        return round(x, nd)
    return x


def metric(name: str, value: float, unit: str, floor: float | None, ratio: float | None, n: int,
           *, samples: list[float] | None = None, **extra: Any) -> dict:
    """One result row. With `samples`, median and p95 are added (same unit as value)."""
    m = {"name": name, "value": _r(value), "unit": unit, "floor": _r(floor), "ratio": _r(ratio),
         "n": int(n)}
    if samples:
        m["median"] = _r(median(samples))
        m["p95"] = _r(percentile(samples, 95))
    m.update({k: _r(v) for k, v in extra.items()})
    return m


def ratio(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or b == 0:
        return None
    return a / b


def ms(xs: list[float]) -> list[float]:
    return [x * 1e3 for x in xs]


def fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.0f}"
    return str(v)


COLUMNS = ["name", "value", "unit", "floor", "ratio", "n", "median", "p95"]


def table(metrics: list[dict]) -> str:
    rows = [COLUMNS] + [[fmt(m.get(c)) for c in COLUMNS] for m in metrics]
    widths = [max(len(r[i]) for r in rows) for i in range(len(COLUMNS))]
    lines = []
    for j, r in enumerate(rows):
        lines.append(" | ".join(c.ljust(w) if i in (0, 2) else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
        if j == 0:
            lines.append("-+-".join("-" * w for w in widths))
    return "\n".join(lines)


def log(*a: Any) -> None:
    print("[bench]", *a, file=sys.stderr, flush=True)


def quiet_logs() -> None:
    import logging

    for name in ("slixmpp", "spade", "rapp", "aiosasl", "asyncio"):
        logging.getLogger(name).setLevel(logging.ERROR)


def spawn(cmd: list[str], **kw) -> subprocess.Popen:
    """A benchmark's child process (a scenario run, a floor measurement) that ends with the benchmark:
    a session of its own (ended whole by end_group) and SIGTERM when the benchmark dies, even killed.
    Its own children (servers, agents, render processes) arm the same signal or watch their parent."""
    from xmpp_server.process import dies_with_parent

    return subprocess.Popen(cmd, start_new_session=True, preexec_fn=dies_with_parent(), **kw)


def end_group(proc: subprocess.Popen, grace_s: float = 5.0) -> None:
    """End a spawned child's whole session: SIGTERM, then SIGKILL after grace_s."""
    for sig, wait in ((signal.SIGTERM, grace_s), (signal.SIGKILL, 1.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return  # nothing of the session is left
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline:
            if proc.poll() is None:
                time.sleep(0.05)
                continue
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.05)


def child_env(settings) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.update(settings.to_env())
    return env


class RobotSystem:
    """A RappSystem (own server, Store, Platform) with the given RApps published and `robots`
    Core Agents (robot i of kind nao/elektron alternately) in one shared World.

        async with RobotSystem(workdir, [ECHO_APP], trace=True) as rs:
            await rs.command(rs.robots[0], "echo", "echo-app finished")
    """

    def __init__(self, workdir: Path, apps: list[Path], *, robots: int = 1, trace: bool = False,
                 house: str = "small", **core_kw):
        self.workdir, self.apps, self.n, self.trace, self.house = Path(workdir), apps, robots, trace, house
        self.core_kw = core_kw  # CoreAgent options, e.g. dynamic_mode="inprocess"
        self.system = None
        self.world = None
        self.robots = []

    @property
    def trace_file(self) -> Path | None:
        return self.workdir / "trace.jsonl" if self.trace else None

    async def __aenter__(self) -> "RobotSystem":
        from scenarios.system import RappSystem
        from robots import World

        quiet_logs()
        self.world = await asyncio.to_thread(World.from_file, self.house, seed=3)
        self.system = RappSystem(self.workdir, trace_file=self.trace_file)
        await self.system.start()
        for app in self.apps:
            await self.system.publish(app)
        await self.add_robots(self.n)
        return self

    async def add_robots(self, count: int) -> None:
        from robots import RobotAPI
        from scenarios.system import wait_until

        new = []
        for _ in range(count):
            i = len(self.robots) + len(new)
            kind = ("nao", "elektron")[i % 2]
            robot = await asyncio.to_thread(self.world.add_robot, kind, f"{kind}{i + 1}")
            new.append(await self.system.add_robot(kind, api=RobotAPI(robot), robot_id=f"{kind}{i + 1}",
                                                   **self.core_kw))
        for h in new:
            await wait_until(lambda: h.core.vocabulary and h.core.listening,
                             60, f"{h.robot_id} listening")
        self.robots.extend(new)

    async def command(self, handle, text: str, expect: str, timeout: float = 120.0) -> str:
        from scenarios.system import wait_until

        start = len(handle.user.received)
        await handle.user.say(handle.core.address, text)
        reply = await handle.user.wait_for(lambda t: expect in t or "problem" in t, timeout=timeout, start=start)
        await wait_until(lambda: handle.core.listening
                         and handle.core.dynamic is None, 30, f"{handle.robot_id} listening again")
        return reply

    async def __aexit__(self, *exc) -> None:
        try:
            if self.system is not None:
                await self.system.stop()
        finally:
            if self.world is not None:
                self.world.close()
