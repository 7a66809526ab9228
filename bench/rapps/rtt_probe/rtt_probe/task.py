"""Times `calls` robot-API get_global_pose and Platform ping round trips (after `warmup` of each),
writes them to rtt.json in the working directory and reports a summary through the Core."""
import json
import time
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
        out = {}
        for name, call in (("robot", self.robot.get_global_pose), ("platform", self.platform.ping)):
            for _ in range(warm):
                await call()
            times = []
            for _ in range(n):
                t0 = time.perf_counter()
                await call()
                times.append(time.perf_counter() - t0)
            out[name] = times
        Path("rtt.json").write_text(json.dumps(out))
        med = {k: sorted(v)[len(v) // 2] * 1e3 for k, v in out.items()}
        await self.report(f"rtt probe done: robot {med['robot']:.2f} ms, platform {med['platform']:.2f} ms")
