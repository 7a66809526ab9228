"""Round trips seen by a real Dynamic Agent (own process, own XMPP login, the real command path):
`robot_rtt` = robot-API get_global_pose served by the Core, `platform_rtt` = the Platform's `ping`.
The benchmark RApp bench/rapps/rtt_probe times the calls inside the Dynamic Agent.

Floor, in the same run and through the same server: a raw slixmpp message round trip between two
plain clients (one echoes every message back), same number of calls. Traces are off for both.
"""
from __future__ import annotations

import asyncio
import json
import shutil
import tempfile
import time
from pathlib import Path

import yaml

from .common import RTT_PROBE, RobotSystem, log, median, metric, ms, percentile, ratio


async def slixmpp_rtt(settings, calls: int, warmup: int = 10, body: str = "x" * 32) -> list[float]:
    from scenarios.user import ChatUser

    class Echo(ChatUser):
        def _on_message(self, msg):
            if msg["body"]:
                self.send_message(mto=msg["from"], mbody=msg["body"], mtype="chat")

    class Pinger(ChatUser):
        def _on_message(self, msg):
            if msg["body"] and self.waiter is not None and not self.waiter.done():
                self.waiter.set_result(time.perf_counter())

    tag = f"{int(time.time() * 1000) % 10**8}"
    echo, pinger = Echo(f"floor-echo-{tag}", settings), Pinger(f"floor-ping-{tag}", settings)
    pinger.waiter = None
    await echo.start()
    await pinger.start()
    to = settings.jid(f"floor-echo-{tag}")
    loop = asyncio.get_running_loop()
    times = []
    try:
        for i in range(warmup + calls):
            pinger.waiter = loop.create_future()
            t0 = time.perf_counter()
            pinger.send_message(mto=to, mbody=body, mtype="chat")
            t1 = await asyncio.wait_for(pinger.waiter, 10)
            if i >= warmup:
                times.append(t1 - t0)
    finally:
        await pinger.stop()
        await echo.stop()
    return times


async def run(quick: bool = True, calls: int | None = None) -> list[dict]:
    calls = calls or (200 if quick else 1000)
    with tempfile.TemporaryDirectory(prefix="bench-rtt-") as tmp:
        app = Path(tmp) / "rtt_probe"
        shutil.copytree(RTT_PROBE, app)
        manifest = yaml.safe_load((app / "manifest.yaml").read_text())
        manifest["params"]["calls"] = calls
        (app / "manifest.yaml").write_text(yaml.safe_dump(manifest))
        async with RobotSystem(Path(tmp) / "run", [app], trace=False) as rs:
            h = rs.robots[0]
            floor_before = await slixmpp_rtt(rs.system.settings, calls // 2)
            reply = await rs.command(h, "rttprobe", "rtt-probe finished", timeout=300)
            if "problem" in reply:
                raise RuntimeError(reply)
            floor_after = await slixmpp_rtt(rs.system.settings, calls - calls // 2)
            result = json.loads(next((rs.workdir / f"core-{h.robot_id}").glob("*rtt-probe/rtt.json")).read_text())
    floor = ms(floor_before + floor_after)
    fmed = median(floor)
    out = []
    for key, name in (("robot", "robot_rtt"), ("platform", "platform_rtt")):
        xs = ms(result[key])
        med = median(xs)
        out.append(metric(name, med, "ms", fmed, ratio(med, fmed), len(xs), samples=xs,
                          floor_p95=percentile(floor, 95), p95_ratio=ratio(percentile(xs, 95), percentile(floor, 95)),
                          goal_ratio=1.5))
        log(f"{name}: median {med:.3f} ms p95 {percentile(xs, 95):.3f} ms; floor median {fmed:.3f} ms")
    return out
