"""Times `calls` robot-API get_global_pose and Platform ping round trips (after `warmup` of each),
writes them to rtt.json in the working directory and reports a summary through the Core.

With `echo` (a plain XMPP client's name that sends every chat message back), each robot call and
each Platform call is preceded by the floor's round trip: a raw slixmpp message from a plain client
in this process to the echo client and back. The three are measured interleaved, call by call, so
the machine's drift (a noisy 2-core VM) affects project and floor alike."""
import asyncio
import json
import time
import uuid
from pathlib import Path

from rapps.sdk import FSM, Step, Task


class ProbeTask(Task):
    def build(self):
        fsm = FSM("rtt", initial="measure")
        fsm.add_state("measure", Step(self.measure), final=True)
        return fsm

    async def measure(self, memory):
        n, warm = int(self.params["calls"]), int(self.params["warmup"])
        echo = self.params.get("echo") or ""
        floor = await FloorPing.start(self.runtime.settings, echo) if echo else None
        calls = [("robot", self.robot.get_global_pose), ("platform", self.platform.ping)]
        if floor is not None:  # the floor's round trip before each call
            calls = [("floor", floor.ping), calls[0], ("floor", floor.ping), calls[1]]
        out = {name: [] for name, _ in calls}
        try:
            for i in range(warm + n):
                for name, call in calls:
                    t0 = time.perf_counter()
                    await call()
                    if i >= warm:
                        out[name].append(time.perf_counter() - t0)
        finally:
            if floor is not None:
                await floor.user.stop()
        Path("rtt.json").write_text(json.dumps(out))
        med = {k: sorted(v)[len(v) // 2] * 1e3 for k, v in out.items()}
        await self.report("rtt probe done: " + ", ".join(f"{k} {v:.2f} ms" for k, v in med.items()))


class FloorPing:
    """A plain slixmpp chat client pinging the echo client."""

    def __init__(self, user, to: str):
        self.user, self.to, self.waiter = user, to, None

    @classmethod
    async def start(cls, settings, echo: str) -> "FloorPing":
        from xmpp_server.chat import ChatUser
        from xmpp_server.credentials import generate_password

        class Pinger(ChatUser):
            def _on_message(self, msg):
                if msg["body"] and probe.waiter is not None and not probe.waiter.done():
                    probe.waiter.set_result(None)

        probe = cls(Pinger(f"floor-ping-{uuid.uuid4().hex[:8]}", settings, password=generate_password()),
                    settings.jid(echo))
        await probe.user.start()
        return probe

    async def ping(self) -> None:
        self.waiter = asyncio.get_running_loop().create_future()
        self.user.send_message(mto=self.to, mbody="x" * 32, mtype="chat")
        await asyncio.wait_for(self.waiter, 10)
