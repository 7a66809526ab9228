"""One-way ACL messages per second between two agents through the server (force_xmpp=True), with
traces on and off; floor in the same run: the same with two raw slixmpp clients.

Rate = messages / (last received - first sent); every message must arrive (no loss).
"""
from __future__ import annotations

import asyncio
import contextlib
import tempfile
import time
from pathlib import Path

from .common import log, median, metric, quiet_logs, ratio

BATCH = 50  # the sender yields to the loop every BATCH messages (lets the transport flush)


class Arrivals:
    """Counts received messages; `done` resolves when `count` have arrived (the time is kept)."""

    def __init__(self, count: int):
        self.count, self.n, self.last = count, 0, 0.0
        self.done = asyncio.get_running_loop().create_future()

    def hit(self) -> None:
        self.n += 1
        if self.n >= self.count:
            self.last = time.perf_counter()
            if not self.done.done():
                self.done.set_result(True)


async def send_all(send, arrivals: Arrivals) -> float:
    """Messages per second: send(i) for every i (awaited if it is a coroutine), until all arrived."""
    t0 = time.perf_counter()
    for i in range(arrivals.count):
        sent = send(i)
        if asyncio.iscoroutine(sent):
            await sent
        if i % BATCH == BATCH - 1:
            await asyncio.sleep(0)
    await asyncio.wait_for(arrivals.done, 60)
    return arrivals.count / (arrivals.last - t0)


async def agents_rate(settings, count: int, tag: str) -> float:
    from agents.base import CyclicBehaviour, RappAgent
    from ontology import core as C

    arrivals = Arrivals(count)

    class Sink(CyclicBehaviour):
        def match(self, msg):
            return True

        async def run(self):
            if await self.receive(timeout=1.0) is not None:
                arrivals.hit()

    sender, receiver = RappAgent(f"msend-{tag}", settings), RappAgent(f"mrecv-{tag}", settings)
    await sender.start()
    await receiver.start()
    receiver.add_behaviour(Sink())
    try:
        return await send_all(lambda i: sender.notify(receiver.address, C.Heartbeat(seq=i), ontology=C.ONTOLOGY,
                                                      action="heartbeat"), arrivals)
    finally:
        await sender.stop()
        await receiver.stop()


@contextlib.asynccontextmanager
async def chat_pair(send_settings, recv_settings, names: tuple[str, str], arrivals: Arrivals):
    """Two raw slixmpp clients, the receiver counting what arrives: (the sender, the receiver's JID)."""
    from scenarios.user import ChatUser

    class Sink(ChatUser):
        def _on_message(self, msg):
            arrivals.hit()

    sender, receiver = ChatUser(names[0], send_settings), Sink(names[1], recv_settings)
    await sender.start()
    await receiver.start()
    try:
        yield sender, recv_settings.jid(names[1])
    finally:
        await sender.stop()
        await receiver.stop()


async def slixmpp_rate(settings, count: int, tag: str, body: str) -> float:
    arrivals = Arrivals(count)
    async with chat_pair(settings, settings, (f"fsend-{tag}", f"frecv-{tag}"), arrivals) as (sender, to):
        return await send_all(lambda i: sender.send_message(mto=to, mbody=body, mtype="chat"), arrivals)


async def run(quick: bool = True, count: int | None = None, rounds: int | None = None) -> list[dict]:
    from agents.messages import make_message
    from ontology.acl import Performative
    from ontology import core as C
    from xmpp_server import EmbeddedServer

    quiet_logs()
    count = count or (2000 if quick else 5000)
    rounds = rounds or (3 if quick else 5)
    # the floor carries the same body as the ACL message (its JSON content), without the metadata
    body = make_message("x@localhost", C.Heartbeat(seq=1), performative=Performative.INFORM,
                        ontology=C.ONTOLOGY, action="heartbeat").body or "x"
    res = {"off": [], "on": [], "floor": []}
    with tempfile.TemporaryDirectory(prefix="bench-msg-") as tmp:
        async with EmbeddedServer(db=Path(tmp) / "xmpp.db") as srv:
            plain = srv.settings(force_xmpp=True)
            traced = srv.settings(force_xmpp=True, trace_file=Path(tmp) / "trace.jsonl")
            for r in range(rounds):  # interleaved: machine noise hits all three alike
                res["floor"].append(await slixmpp_rate(plain, count, f"{r}", body))
                res["off"].append(await agents_rate(plain, count, f"off{r}"))
                res["on"].append(await agents_rate(traced, count, f"on{r}"))
    fmed = median(res["floor"])
    out = []
    for key, name in (("off", "messages"), ("on", "messages_traced")):
        med = median(res[key])
        # higher is better: ratio = floor / value so that, like every other row, > 1 means slower
        out.append(metric(name, med, "msg/s", fmed, ratio(fmed, med), rounds * count, samples=res[key],
                          messages_per_round=count, ratio_meaning="floor/value (>1: slower than floor)"))
        log(f"{name}: {med:.0f} msg/s, floor {fmed:.0f} msg/s")
    return out
