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

from behaviours import FSM
from rapps.sdk import Step, Task


class ProbeTask(Task):
    def build(self):
        fsm = FSM("rtt", initial="measure")
        fsm.add_state("measure", Step(self.measure), final=True)
        return fsm

    async def measure(self, memory):
        n, warm = int(self.params["calls"]), int(self.params["warmup"])
        floor = await FloorPing.start(self.runtime.settings, self.params.get("echo") or "")
        out = {"robot": [], "platform": [], "floor": []}
        try:
            for i in range(warm + n):
                for name, call in (("floor", floor.ping), ("robot", self.robot.get_global_pose),
                                   ("floor", floor.ping), ("platform", self.platform.ping)):
                    t0 = time.perf_counter()
                    if await call() is False:
                        continue
                    if i >= warm:
                        out[name].append(time.perf_counter() - t0)
        finally:
            await floor.stop()
        Path("rtt.json").write_text(json.dumps(out))
        med = {k: sorted(v)[len(v) // 2] * 1e3 for k, v in out.items() if v}
        await self.report("rtt probe done: " + ", ".join(f"{k} {v:.2f} ms" for k, v in med.items()))


class FloorPing:
    """A plain slixmpp chat client pinging `echo`; ping() returns False when there is no echo."""

    def __init__(self, user=None, to: str = ""):
        self.user, self.to, self.waiter = user, to, None

    @classmethod
    async def start(cls, settings, echo: str) -> "FloorPing":
        if not echo:
            return cls()
        from scenarios.user import ChatUser

        probe = cls(to=settings.jid(echo))

        class Pinger(ChatUser):
            def _on_message(self, msg):
                if msg["body"] and probe.waiter is not None and not probe.waiter.done():
                    probe.waiter.set_result(None)

        probe.user = Pinger(f"floor-ping-{uuid.uuid4().hex[:8]}", settings)
        await probe.user.start()
        return probe

    async def ping(self):
        if self.user is None:
            return False
        self.waiter = asyncio.get_running_loop().create_future()
        self.user.send_message(mto=self.to, mbody="x" * 32, mtype="chat")
        await asyncio.wait_for(self.waiter, 10)

    async def stop(self):
        if self.user is not None:
            await self.user.stop()
