"""`rapp run demo`: two agents on the embedded server, a FIPA-Request exchange, and its trace.

The smallest complete run: start the server, log two agents in, ask the Platform-like agent for a
service three times (request -> agree -> inform, through the XMPP server), print the trace.
"""
from __future__ import annotations

import argparse
import asyncio
import tempfile
from pathlib import Path

from agents.base import RappAgent
from agents.responder import Responder
from agents.tracing import read_trace
from ontology.registry import Action, Content, action
from xmpp_server import EmbeddedServer


class Greeting(Content):
    text: str


@action("greet", ontology="demo", reply=Greeting)
class Greet(Action):
    name: str


async def _greet(req: Greet, ctx) -> Greeting:
    return Greeting(text=f"Hello {req.name}, I am {ctx.info.ontology}'s responder")


async def run_demo(out_dir: Path) -> Path:
    trace = out_dir / "trace.jsonl"
    async with EmbeddedServer() as server:
        settings = server.settings(trace_file=trace, force_xmpp=True)
        alice, bob = RappAgent("alice", settings), RappAgent("bob", settings)
        await alice.start()
        await bob.start()
        responder = Responder("demo", {"greet": _greet}, agree=True)
        bob.activate("greeter", responder, responder.make_template())
        for name in ("Ada", "Grace", "Barbara"):
            reply = await alice.request(bob.address, Greet(name=name), timeout=5)
            print(f"alice <- bob: {reply.text}")
        await alice.stop()
        await bob.stop()
    return trace


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="rapp run demo", description=__doc__.split("\n\n")[0].split(": ", 1)[1],
                                epilog=__doc__.split("\n\n")[1])
    p.add_argument("--out", default=None, help="directory for the trace (default: a new temp dir)")
    a = p.parse_args(argv)
    out = Path(a.out or tempfile.mkdtemp(prefix="rapp-demo-"))
    out.mkdir(parents=True, exist_ok=True)
    trace = asyncio.run(run_demo(out))
    try:
        from scenarios import trace_report
        print(trace_report.table(read_trace(trace)))
    except ImportError:
        for r in read_trace(trace):
            print(r)
    print(f"trace: {trace}")
    return 0
