"""Round trips seen by a real Dynamic Agent (own process, own XMPP login, the real command path):
`robot_rtt` = robot-API get_global_pose served by the Core, `platform_rtt` = the Platform's `ping`.
The benchmark RApp bench/rapps/rtt_probe times the calls inside the Dynamic Agent.

Floor, in the same run and through the same server: a raw slixmpp message round trip between two
plain clients, one in the Dynamic Agent's process, one (echoing every message back) in the Core's:
the same two processes as a robot call. The probe measures floor, robot, floor, platform, call by
call, so the machine's drift affects all alike. Traces are off.
"""
from __future__ import annotations

import json
import shutil
import tempfile
import time
from pathlib import Path

import yaml

from agents.sandbox import Sandbox

from .common import RTT_PROBE, RobotSystem, log, median, metric, ms, percentile, ratio


async def echo_client(settings, name: str):
    """The floor's far end: a plain slixmpp client in this process that sends every chat back."""
    from scenarios.user import ChatUser

    class Echo(ChatUser):
        def _on_message(self, msg):
            if msg["body"]:
                self.send_message(mto=msg["from"], mbody=msg["body"], mtype="chat")

    echo = Echo(name, settings)
    await echo.start()
    return echo


async def run(quick: bool = True, calls: int | None = None) -> list[dict]:
    calls = calls or (200 if quick else 1000)
    with tempfile.TemporaryDirectory(prefix="bench-rtt-") as tmp:
        app = Path(tmp) / "rtt_probe"
        shutil.copytree(RTT_PROBE, app)
        manifest = yaml.safe_load((app / "manifest.yaml").read_text())
        echo_name = f"floor-echo-{int(time.time() * 1000) % 10**8}"
        manifest["params"].update(calls=calls, echo=echo_name)
        (app / "manifest.yaml").write_text(yaml.safe_dump(manifest))
        # the probe RApp measures its floor with a plain client of its own: a second XMPP connection
        async with RobotSystem(Path(tmp) / "run", [app], trace=False, sandbox=Sandbox(max_connections=2)) as rs:
            h = rs.robots[0]
            echo = await echo_client(rs.system.settings, echo_name)
            try:
                reply = await rs.command(h, "rttprobe", "rtt-probe finished", timeout=300)
            finally:
                await echo.stop()
            if "problem" in reply:
                raise RuntimeError(reply)
            result = json.loads(next((rs.workdir / f"core-{h.robot_id}").glob("*rtt-probe/rtt.json")).read_text())
    floor = ms(result["floor"])
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
