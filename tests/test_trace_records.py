"""The trace records of ontology/trace.py: every event name the code writes is a member of its enum
(and every member is written somewhere), and the traces of real runs validate."""
from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from agents.tracing import TraceWriter, read_trace
from ontology.trace import (AgentEvent, BehaviourEvent, MessageRecord, RecordKind, StructureEvent,
                            StructureRecord, is_valid, parse_record)

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "data" / "golden_trace.jsonl"
ENUMS = {e.__name__: e for e in (RecordKind, StructureEvent, AgentEvent, BehaviourEvent)}
SOURCES = ("agents", "behaviours", "robots", "rapps", "scenarios", "bench", "cli", "xmpp_server")  # the server traces logins


def _strings(node: ast.AST) -> list[str] | None:
    """The string literals an argument can be ("a", RecordKind.A, or "a" if x else "b"); None if it
    is not made of literals and members of the trace enums only."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in ENUMS:
        return [ENUMS[node.value.id][node.attr].value]
    if isinstance(node, ast.IfExp):
        body, orelse = _strings(node.body), _strings(node.orelse)
        return None if body is None or orelse is None else body + orelse
    return None


def _calls():
    for pkg in SOURCES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
                    yield f"{path.relative_to(ROOT)}:{node.lineno}", node


def emitted() -> dict[str, dict[str, list[str]]]:
    """{kind: {event or "": [where]}} of every trace record written with literal names:
    record_structure("event", ...), tracer.record("kind", event="...", ...), ctx.trace("kind", ...),
    task._trace("kind", event=...)."""
    out: dict[str, dict[str, list[str]]] = {}
    for where, call in _calls():
        name = call.func.attr
        if name == "record_structure":
            names = _strings(call.args[0]) if call.args else None
            assert names is not None, f"{where}: record_structure with a non-literal event name"
            for event in names:
                out.setdefault("structure", {}).setdefault(event, []).append(where)
        elif name in ("record", "trace", "_trace") and call.args:  # _trace: a RApp task's (rapps/sdk)
            kinds = _strings(call.args[0])
            if kinds is None:  # a pass-through (TraceWriter.record's own callers are checked)
                continue
            event = next((k.value for k in call.keywords if k.arg == "event"), None)
            for kind in kinds:
                if event is None:
                    out.setdefault(kind, {}).setdefault("", []).append(where)
                else:
                    events = _strings(event)
                    assert events is not None or kind == "structure", f"{where}: non-literal {kind} event"
                    for e in events or []:
                        out.setdefault(kind, {}).setdefault(e, []).append(where)
    return out


def test_every_emitted_name_is_in_the_ontology():
    found = emitted()
    assert set(found) <= set(RecordKind), found.keys()
    assert set(found["structure"]) <= set(StructureEvent), sorted(set(found["structure"]) - set(StructureEvent))
    assert set(found["agent"]) <= set(AgentEvent)
    assert set(found["behaviour"]) <= set(BehaviourEvent)
    assert set(found["state"]) == {"enter"}


def test_every_structure_event_is_emitted():
    """No dead names (the docstring of agents/tracing.py once listed a 'finish' nobody wrote)."""
    found = emitted()
    assert set(StructureEvent) == set(found["structure"]), sorted(set(StructureEvent) - set(found["structure"]))
    assert set(AgentEvent) == set(found["agent"])
    assert "finish" not in set(StructureEvent)


def test_golden_trace_of_a_real_run_validates():
    lines = GOLDEN.read_text(encoding="utf-8").splitlines()
    records = [parse_record(json.loads(line)) for line in lines]
    assert len(records) == len(lines) == 202
    assert {r.kind for r in records} == {"message", "agent", "behaviour", "structure", "state", "dropped"}
    spawn = next(r for r in records if isinstance(r, StructureRecord) and r.event == StructureEvent.SPAWN)
    assert spawn.dynamic.startswith("dyn-nao1-golden-demo-")  # the event's own fields are kept
    chat = next(r for r in records if isinstance(r, MessageRecord) and r.performative == "chat")
    assert chat.path == "xmpp" and chat.conversation_id == ""


async def test_trace_of_the_demo_run_validates(tmp_path):
    """`rapp run demo`: two agents on the embedded XMPP server, three requests."""
    from scenarios.demo import run_demo

    trace = await run_demo(tmp_path)
    raw = read_trace(trace)
    assert len(raw) > 10 and read_trace(trace, validate=True) == raw
    assert {r["kind"] for r in raw} >= {"message", "agent", "behaviour"}
    # its recording (issue 45: every `rapp run` scenario): each ACL message once, on its sender's channel
    from mcap.reader import make_reader

    with open(tmp_path / "run.mcap", "rb") as f:
        messages = [(c.topic, s.name, json.loads(m.data)) for s, c, m in make_reader(f).iter_messages()]
    acl = {(topic, m["performative"], m["action"]) for topic, name, m in messages if name == "rapp.AclMessage"}
    assert {("/acl/alice", "request", "greet"), ("/acl/bob", "agree", "greet"), ("/acl/bob", "inform", "greet")} <= acl
    informs = [m for topic, _, m in messages if topic == "/acl/bob" and m["performative"] == "inform"]
    assert len(informs) == 3 and informs[0]["content"]["text"].startswith("Hello Ada")


def test_invalid_records():
    base = {"t": 1.0, "pid": 1, "agent": "core@localhost"}
    assert is_valid({**base, "kind": "structure", "event": "spawn", "dynamic": "d@localhost"})
    assert not is_valid({**base, "kind": "structure", "event": "finish"})  # not a real event
    assert not is_valid({**base, "kind": "no-such-kind"})
    assert not is_valid({**base, "kind": "message", "dir": "send"})  # fields missing
    with pytest.raises(ValueError):
        parse_record({**base, "kind": "behaviour", "event": "paused", "behaviour": "b"})


def test_writing_does_not_validate(tmp_path):
    """Tracing is on every message: the writer writes what it is given, the reader checks."""
    path = tmp_path / "t.jsonl"
    w = TraceWriter(path)
    w.record("structure", event="no-such-event", agent="a@localhost")
    w.record(RecordKind.STRUCTURE, event=StructureEvent.RESUME, agent="a@localhost", robot="r")
    w.close()
    assert [r["event"] for r in read_trace(path)] == ["no-such-event", "resume"]
    assert [r["event"] for r in read_trace(path, validate=True)] == ["resume"]


def test_a_message_record_written_as_text_is_the_json_of_its_fields(tmp_path):
    """TraceWriter.message builds the line itself (one per message and side): it must be the JSON
    the generic writer would give, whatever the content holds, and a valid MessageRecord."""
    fields = dict(dir="recv", agent="a@localhost", sender="b@localhost", receiver="a@localhost",
                  performative="inform", conversation_id="c-1", ontology="core", action="report",
                  message_id="m-1", in_reply_to="m-0", path="xmpp", size=42,
                  content='{"text": "quote \\" back\\\\slash\\nnew line, tab\\t, é ☃, </x>, \\u0001"}' + "\n\t\x01 real control characters")
    writer = TraceWriter(tmp_path / "t.jsonl")
    writer.message(**{k if k != "dir" else "direction": v for k, v in fields.items()}, feedback=True)
    writer.message(**{k if k != "dir" else "direction": v for k, v in fields.items()})
    writer.record(RecordKind.MESSAGE, **fields)
    text, _, generic = [json.loads(line) for line in (tmp_path / "t.jsonl").read_text().splitlines()]
    assert {k: v for k, v in text.items() if k not in ("t", "feedback")} == {k: v for k, v in generic.items() if k != "t"}
    assert text["feedback"] is True and abs(text["t"] - generic["t"]) < 5
    assert len(read_trace(tmp_path / "t.jsonl", validate=True)) == 3
