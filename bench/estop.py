"""Emergency stop latency (paper 003): from the owner's "stop" (a chat message sent) to the robot's
base at zero velocity (its motion controller gone: the kinematic base makes no further step), while
a RApp drives it (the echo RApp's "cruise": move_vel 0.3 m/s). After each stop: "cancel", "resume".

Floor, in the same run and through the same server: the delivery of that same chat message, from
the owner's send to the Core's record of the command (its `command` structure record). The ratio
says what the stop adds to just hearing the word: parsing it, latching, halting every effector.
Clocks: the owner, the Core and the robot are in this process (time.time() throughout)."""
from __future__ import annotations

import asyncio
import tempfile
import time
from pathlib import Path

from ontology.trace import RecordKind, StructureEvent

from .common import ECHO_APP, RobotSystem, log, median, metric, ratio

GOAL_MS = 100.0  # an owner's stop must act within a tenth of a second on this machine


def _variant(root: Path) -> Path:
    import shutil

    import yaml
    dest = root / "cruise-echo"
    shutil.copytree(ECHO_APP, dest)
    m = yaml.safe_load((dest / "manifest.yaml").read_text())
    m.update(name="cruise-echo", keywords=["cruiseecho"])
    m["params"].update(behaviour="cruise")
    (dest / "manifest.yaml").write_text(yaml.safe_dump(m))
    return dest


async def _until(pred, timeout: float, what: str) -> float:
    """When `pred()` became true (polled every 0.5 ms: the latency is a few ms)."""
    from scenarios.system import wait_until
    await wait_until(pred, timeout, f"estop bench: {what}", interval=0.0005)
    return time.time()


async def run(quick: bool = True, n: int | None = None) -> list[dict]:
    n = n or (5 if quick else 20)
    from agents.tracing import read_trace

    sent: list[tuple[float, float]] = []  # (owner's send, zero velocity) per measured stop
    with tempfile.TemporaryDirectory(prefix="bench-estop-") as tmp:
        app = _variant(Path(tmp))
        async with RobotSystem(Path(tmp) / "run", [app], trace=True, dynamic_mode="inprocess") as rs:
            h = rs.robots[0]
            robot, core, user = h.api.robot, h.core, h.user
            for i in range(n + 1):  # the first is a warm-up
                start = len(user.received)
                await user.say(core.address, "cruiseecho")
                await _until(lambda: "base" in robot.controllers and core.robot_commands.driving, 30, "driving")
                await asyncio.sleep(0.3)
                t0 = time.time()
                await user.say(core.address, "stop")
                t1 = await _until(lambda: "base" not in robot.controllers, 10, "zero velocity")
                await user.wait_for(lambda t: t.startswith("Emergency stop"), timeout=10, start=start)
                await rs.command(h, "cancel", "cruise-echo ended")
                await user.say(core.address, "resume")
                await user.wait_for(lambda t: t.startswith("Resumed"), timeout=10, start=start)
                if i:
                    sent.append((t0, t1))
            records = await asyncio.to_thread(read_trace, rs.trace_file)  # once, after the runs
    heard = sorted(r["t"] for r in records if r["kind"] == RecordKind.STRUCTURE
                   and r.get("event") == StructureEvent.COMMAND and r.get("text") == "stop")
    stops, floors = [], []
    for t0, t1 in sent:
        delivered = next((t for t in heard if t >= t0), None)
        if delivered is not None:
            stops.append((t1 - t0) * 1e3)
            floors.append((delivered - t0) * 1e3)
    med, floor = median(stops), median(floors)
    log(f"estop: owner's stop -> zero velocity median {med:.1f} ms (chat delivery {floor:.1f} ms), n={len(stops)}")
    return [metric("estop_latency", med, "ms", floor, ratio(med, floor), len(stops), samples=stops,
                   goal_ms=GOAL_MS)]
