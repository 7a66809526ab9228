"""Live progress lines of `rapp run`, read from a trace as agents of several processes write it."""
from __future__ import annotations

import asyncio
import io

from agents.tracing import TraceWriter
from scenarios.progress import follow


def chat(sender: str, receiver: str, text: str) -> dict:
    """The fields of a chat message record, as agents.base traces it."""
    return dict(agent=sender, sender=sender, receiver=receiver, performative="chat", conversation_id="",
                ontology="", action="", message_id="", in_reply_to="", path="xmpp", size=len(text),
                content=text)


async def test_progress_follows_the_trace_as_it_grows(tmp_path):
    path, out = tmp_path / "trace.jsonl", io.StringIO()
    writer = TraceWriter(path)
    follower = asyncio.create_task(follow(path, pose=lambda: (1.0, 2.0, 0.5), out=out, period=0.05))
    writer.record("state", event="enter", agent="core-nao1@localhost", fsm="core", state="s3_listen")
    writer.record("message", dir="send", **chat("core-nao1@localhost", "alice@localhost",
                                                "Starting hazard-detection."))
    await asyncio.sleep(0.3)
    assert "core: s3_listen" in out.getvalue() and "Starting hazard-detection." in out.getvalue()
    writer.record("state", event="enter", agent="dyn-x@localhost", fsm="hazard", state="localize")
    writer.record("structure", event="resume", agent="core-nao1@localhost", robot="nao1")
    writer.record("message", dir="recv", **dict(chat("core-nao1@localhost", "x@localhost", "not shown"),
                                                agent="x@localhost", performative="inform"))
    writer.record("structure", event="no-such-event", agent="core-nao1@localhost", to="y@localhost")
    follower.cancel()
    await follower  # the lines written before the stop are still printed
    text = out.getvalue()
    assert "rapp hazard: localize" in text and "core-nao1: resume" in text and "not shown" not in text
    assert "no-such-event" not in text  # not a record of ontology.trace: skipped like a broken line
    assert "robot at x=1.00 y=2.00 theta=0.50" in text
    writer.close()
