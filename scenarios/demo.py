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
from agents.tracing import BODIES, read_trace, record_bodies, stop_recording_bodies
from ontology.registry import Action, Content, action
from xmpp_server import EmbeddedServer

from .mcap_export import export_mcap
from .recording import MCAP_FILE


class Greeting(Content):
    text: str


@action("greet", ontology="demo", reply=Greeting)
class Greet(Action):
    name: str


async def _greet(req: Greet, ctx) -> Greeting:
    return Greeting(text=f"Hello {req.name}, I am {ctx.info.ontology}'s responder")


async def run_demo(out_dir: Path, record: bool = True) -> Path:
    """The trace's path; `record`: the messages' whole bodies beside it and run.mcap (docs/recordings.md)."""
    trace = out_dir / "trace.jsonl"
    trace.unlink(missing_ok=True)
    (out_dir / MCAP_FILE).unlink(missing_ok=True)
    if record:
        (out_dir / BODIES).unlink(missing_ok=True)
        record_bodies(trace)
    try:
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
    finally:
        if record:
            stop_recording_bodies(trace)
    if record:
        await asyncio.to_thread(export_mcap, out_dir, out_dir / MCAP_FILE)
    return trace


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="rapp run demo", description=__doc__.split("\n\n")[0].split(": ", 1)[1],
                                epilog=__doc__.split("\n\n")[1])
    p.add_argument("--out", default=None, help="directory for the trace and run.mcap (default: a new temp dir)")
    p.add_argument("--no-record", action="store_true", help="the trace only: no message bodies nor run.mcap "
                                                             "(docs/recordings.md)")
    a = p.parse_args(argv)
    out = Path(a.out or tempfile.mkdtemp(prefix="rapp-demo-"))
    out.mkdir(parents=True, exist_ok=True)
    trace = asyncio.run(run_demo(out, record=not a.no_record))
    try:
        from scenarios import trace_report
        print(trace_report.table(read_trace(trace)))
    except ImportError:
        for r in read_trace(trace):
            print(r)
    print(f"trace: {trace}")
    if not a.no_record:
        print(f"recording: {out / MCAP_FILE} (Foxglove, Lichtblick; docs/recordings.md)")
    return 0
