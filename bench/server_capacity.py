"""What a message costs the XMPP server, for the capacity model (docs/capacity.md).

    python -m bench.server_capacity [--count 3000] [--big-count 300] [--json FILE]

Two raw slixmpp clients (bench/messages.py's floor) send one-way messages through: the embedded
server (pyjabber), one ejabberd node, and a two-node ejabberd cluster with the sender on node 1 and
the receiver on node 2 (each message crosses the cluster). Two bodies: SMALL_BODY characters (most
of a task's messages: a request, an answer, a heartbeat with its ACL metadata) and BIG_BODY (a
camera frame's hop is ~160 kB). Reported per configuration and body: messages/s (bounded by the one Python client on
each side as much as by the server), and the server's CPU microseconds per message (its whole
process tree, /proc), the figure a server's capacity follows from. ejabberd is skipped, said so,
where it is not installed. Run it alone, under the shared CPU lock.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from .common import log
from .messages import Arrivals, chat_pair, send_all
from .proc_cpu import ProcessKinds, ProcessSampler

SMALL_BODY = 500
BIG_BODY = 100_000


async def rate(send_settings, recv_settings, count: int, tag: str, body: str, server_pids: list[int]) -> dict:
    arrivals = Arrivals(count)
    async with chat_pair(send_settings, recv_settings, (f"ssend-{tag}", f"srecv-{tag}"), arrivals) as (sender, to):
        samplers = [ProcessSampler(ProcessKinds(pid, "server")) for pid in server_pids]
        marks = [s.mark() for s in samplers]
        client0 = time.process_time()
        per_s = await send_all(lambda i: sender.send_message(mto=to, mbody=body, mtype="chat"), arrivals)
        client_s = time.process_time() - client0
        server_s = sum(s.since(m)["cpu_s"].get("server", 0.0) for s, m in zip(samplers, marks))
    return {"messages": count, "body_chars": len(body), "msg_per_s": round(per_s),
            "server_cpu_us_per_msg": round(server_s / count * 1e6, 1),
            "clients_cpu_us_per_msg": round(client_s / count * 1e6, 1)}


async def measure(count: int, big_count: int) -> list[dict]:
    from xmpp_server import EmbeddedServer
    from xmpp_server.ejabberd import EjabberdCluster, EjabberdNode, ejabberd_binary

    small, big = "x" * SMALL_BODY, "x" * BIG_BODY
    out = []

    async def both(name: str, send_settings, recv_settings, pids: list[int]) -> None:
        for body, n, size in ((small, count, "small"), (big, big_count, "big")):
            r = await rate(send_settings, recv_settings, n, f"{name}-{size}", body, pids)
            out.append({"server": name, "body": size, **r})
            log(f"{name} {size}: {r}")

    with tempfile.TemporaryDirectory(prefix="bench-srvcap-") as tmp:
        async with EmbeddedServer(db=Path(tmp) / "xmpp.db") as srv:
            s = srv.settings(force_xmpp=True)
            await both("embedded", s, s, [srv.proc.pid])
        if ejabberd_binary() is None:
            log("ejabberd is not installed: its rows are skipped")
            return out
        node = await EjabberdNode(workdir=Path(tmp) / "ej1").astart()
        try:
            s = node.settings(force_xmpp=True)
            await both("ejabberd", s, s, [node.proc.pid])
        finally:
            await asyncio.to_thread(node.close)
        cluster = await EjabberdCluster(nodes=2, workdir=Path(tmp) / "cluster").astart()
        try:
            await both("ejabberd-2-nodes-across", cluster.settings(0, force_xmpp=True),
                       cluster.settings(1, force_xmpp=True), [n.proc.pid for n in cluster.nodes])
        finally:
            await asyncio.to_thread(cluster.close)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.server_capacity", description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=3000, help="small messages per configuration")
    ap.add_argument("--big-count", type=int, default=300, help=f"messages of {BIG_BODY} characters per configuration")
    ap.add_argument("--json", metavar="FILE")
    a = ap.parse_args(argv)
    started, load = time.strftime("%Y-%m-%d %H:%M:%S"), os.getloadavg()
    rows = asyncio.run(measure(a.count, a.big_count))
    print("| server | body | msg/s | server CPU us / msg | clients CPU us / msg |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['server']} | {r['body']} ({r['body_chars']} chars) | {r['msg_per_s']} | {r['server_cpu_us_per_msg']}"
              f" | {r['clients_cpu_us_per_msg']} |")
    if a.json:
        Path(a.json).write_text(json.dumps({"started": started, "load_at_start": load, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
