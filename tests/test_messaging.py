"""FIPA-Request over the real embedded XMPP server: happy path, bad input, timeouts, traces."""
from __future__ import annotations

import asyncio
import json

import pytest
from pydantic import Field

from agents.base import RappAgent
from agents.errors import NotUnderstood, RequestFailed, RequestRefused, RequestTimeout, Refusal
from agents.messages import make_message
from agents.responder import Responder
from agents.tracing import read_trace
from ontology.acl import Performative
from ontology.registry import Action, Content, action
from xmpp_server import EmbeddedServer


class Sum(Content):
    total: int


@action("add", ontology="test-math", reply=Sum)
class Add(Action):
    a: int
    b: int = Field(ge=0)


@action("divide", ontology="test-math", reply=Sum)
class Divide(Action):
    a: int
    b: int


@action("secret", ontology="test-math", reply=Sum)
class Secret(Action):
    pass


async def _add(req: Add, ctx) -> Sum:
    return Sum(total=req.a + req.b)


async def _divide(req: Divide, ctx) -> Sum:
    return Sum(total=req.a // req.b)


async def _secret(req: Secret, ctx) -> Sum:
    raise Refusal(f"{ctx.sender} may not ask for the secret", code="forbidden")


async def start_pair(settings, unique, agree=True):
    server = RappAgent(unique("calc"), settings)
    client = RappAgent(unique("user"), settings)
    await server.start()
    await client.start()
    responder = Responder("test-math", {"add": _add, "divide": _divide, "secret": _secret}, agree=agree)
    server.activate("math", responder, responder.make_template())
    return server, client


def messages(trace, conversation=None):
    return [r for r in trace if r["kind"] == "message"
            and (conversation is None or r["conversation_id"] == conversation)]


async def test_request_agree_inform_and_trace(settings, unique, trace_file):
    server, client = await start_pair(settings, unique)
    try:
        reply = await client.request(server.address, Add(a=2, b=3), timeout=5)
        assert reply == Sum(total=5)
        sends = [r for r in messages(read_trace(trace_file)) if r["dir"] == "send"]
        assert [r["performative"] for r in sends] == ["request", "agree", "inform"]
        assert len({r["conversation_id"] for r in sends}) == 1
        assert {r["path"] for r in sends} == {"direct"}  # same process: SPADE's shortcut, traced
    finally:
        await client.stop()
        await server.stop()


async def test_forced_xmpp_delivery_is_traced_in_order(xmpp_server, unique, trace_file):
    settings = xmpp_server.settings(trace_file=trace_file, force_xmpp=True)
    server, client = await start_pair(settings, unique)
    try:
        for i in range(3):
            assert (await client.request(server.address, Add(a=i, b=1), timeout=5)).total == i + 1
        trace = read_trace(trace_file)
        recvs = [r for r in messages(trace) if r["dir"] == "recv"]
        assert recvs and {r["path"] for r in recvs} == {"xmpp"}
        convs = []
        for r in messages(trace):
            if r["conversation_id"] not in convs:
                convs.append(r["conversation_id"])
        assert len(convs) == 3
        for conv in convs:
            recs = messages(trace, conv)
            for direction in ("send", "recv"):
                assert [r["performative"] for r in recs if r["dir"] == direction] == \
                    ["request", "agree", "inform"]
            # every message is received after it was sent
            for perf in ("request", "agree", "inform"):
                sent = next(r["t"] for r in recs if r["dir"] == "send" and r["performative"] == perf)
                got = next(r["t"] for r in recs if r["dir"] == "recv" and r["performative"] == perf)
                assert sent <= got
            # FIPA reply-with / in-reply-to survive the wire (reply-with travels as the stanza id)
            sent = {r["performative"]: r for r in recs if r["dir"] == "send"}
            got = {r["performative"]: r for r in recs if r["dir"] == "recv"}
            for perf in ("request", "agree", "inform"):
                assert got[perf]["message_id"] == sent[perf]["message_id"] != ""
            assert got["inform"]["in_reply_to"] == sent["request"]["message_id"]
    finally:
        await client.stop()
        await server.stop()


async def test_bad_content_and_unknown_action_get_not_understood(settings, unique):
    server, client = await start_pair(settings, unique, agree=False)
    try:
        raw = make_message(server.address, None, performative=Performative.REQUEST,
                           ontology="test-math", action="add")
        raw.body = "{not json"
        with pytest.raises(NotUnderstood, match="malformed JSON"):
            await _raw_request(client, raw)
        with pytest.raises(NotUnderstood, match=r"b: Input should be greater than or equal to 0"):
            await client.request(server.address, Add.model_construct(a=1, b=-4), timeout=5)
        unknown = make_message(server.address, None, performative=Performative.REQUEST,
                               ontology="test-math", action="multiply")
        unknown.body = json.dumps({"a": 1})
        with pytest.raises(NotUnderstood, match="unknown action 'multiply'"):
            await _raw_request(client, unknown)
        with pytest.raises(RequestFailed, match="ZeroDivisionError"):
            await client.request(server.address, Divide(a=1, b=0), timeout=5)
        with pytest.raises(RequestRefused, match="may not ask"):
            await client.request(server.address, Secret(), timeout=5)
        # still alive and answering
        assert (await client.request(server.address, Add(a=40, b=2), timeout=5)).total == 42
    finally:
        await client.stop()
        await server.stop()


async def _raw_request(client: RappAgent, msg):
    """Send a hand-made request and interpret the answer the way request() does."""
    from ontology import acl
    conv = msg.get_metadata(acl.CONVERSATION_ID)
    q: asyncio.Queue = asyncio.Queue()
    client._pending[conv] = q
    try:
        await client.send(msg)
        answer = await asyncio.wait_for(q.get(), 5)
        body = json.loads(answer.body)
        perf = answer.get_metadata("performative")
        if perf == "not-understood":
            raise NotUnderstood(body["reason"])
        return answer
    finally:
        client._pending.pop(conv, None)


async def test_request_to_silent_agent_times_out(settings, unique):
    silent = RappAgent(unique("silent"), settings)
    client = RappAgent(unique("user"), settings)
    await silent.start()
    await client.start()
    silent.on_unhandled = lambda *a: asyncio.sleep(0)  # never answers anything
    silent._unhandled = lambda msg, info: asyncio.sleep(0)
    try:
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        with pytest.raises(RequestTimeout, match="did not answer add within 0.5s"):
            await client.request(silent.address, Add(a=1, b=1), timeout=0.5)
        assert 0.45 <= loop.time() - t0 < 1.5
    finally:
        await client.stop()
        await silent.stop()


async def test_known_action_without_active_responder_is_refused(settings, unique):
    server, client = await start_pair(settings, unique)
    try:
        server.deactivate("math")
        assert "math" not in server.active_behaviours()
        with pytest.raises(RequestRefused, match="does not serve test-math/add"):
            await client.request(server.address, Add(a=1, b=1), timeout=5)
    finally:
        await client.stop()
        await server.stop()


async def test_second_server_starts_in_same_session():
    async with EmbeddedServer() as second:
        settings = second.settings()
        a = RappAgent("a", settings)
        b = RappAgent("b", settings)
        await a.start()
        await b.start()
        responder = Responder("test-math", {"add": _add})
        a.activate("math", responder, responder.make_template())
        assert (await b.request(a.address, Add(a=1, b=2), timeout=5)).total == 3
        await a.stop()
        await b.stop()
    assert not second.running()


async def test_message_forms_stay_raw_xml_in_the_whole_process():
    """An agent's client keeps slixmpp from building stanza objects for message data forms (SPADE
    reads the metadata from the raw XML), also after another client of the process loads XEP-0004."""
    from slixmpp import ClientXMPP
    from slixmpp.stanza import Message

    from xmpp_server.compat import rapp_xmpp_client_class

    RappXMPPClient = rapp_xmpp_client_class()

    RappXMPPClient("forms-a@localhost", "pw", False, True)  # in-band registration loads XEP-0004
    other = ClientXMPP("forms-b@localhost", "pw")
    other.register_plugin("xep_0077")
    other.register_plugin("xep_0004")
    assert "{jabber:x:data}x" not in Message.plugin_tag_map and "form" not in Message.plugin_attrib_map


def test_stanza_reader_reads_our_writer_and_plain_spade():
    """read_message walks the stanza's XML itself: it must read what message_xml writes (markup in
    the body, a thread, the stanza id as reply-with) and what a plain SPADE agent sends (its form puts
    the title after the fields and types every field)."""
    import slixmpp
    from slixmpp.stanza import Message as Stanza
    from slixmpp.xmlstream import ET
    from spade.message import Message

    from agents.stanza import message_xml, read_message
    from xmpp_server.compat import metadata_of

    ours = make_message("b@localhost/r", None, performative=Performative.INFORM, ontology="core", action="x")
    ours.sender, ours.body, ours.thread = "a@localhost/s", '{"t": "<a & \'b\'>"}', "th-1"
    wire = message_xml(ours).replace("<message ", '<message xmlns="jabber:client" ', 1)
    got = read_message(Stanza(xml=ET.fromstring(wire)))
    assert (str(got.to), str(got.sender), got.body, got.thread) == ("b@localhost/r", "a@localhost/s", ours.body, "th-1")
    assert metadata_of(got) == metadata_of(ours)  # reply_with came back from the stanza id

    client = slixmpp.ClientXMPP("c@localhost", "x")
    client.register_plugin("xep_0004")
    plain = Message(to="b@localhost", sender="c@localhost", body="hi", thread="t2",
                    metadata={"performative": "inform", "k": "v"}).prepare(client)
    got = read_message(plain)
    assert (got.body, got.thread, got.get_metadata("k")) == ("hi", "t2", "v")
    assert got.get_metadata("reply_with") == plain["id"]


def test_compact_metadata_is_one_element_and_falls_back_to_the_form():
    """Our agents send the metadata as one element's attributes; a key that cannot be an attribute
    name, a value an attribute would normalise (a newline) or form=True give SPADE's form; both read
    back to the same metadata."""
    from slixmpp.stanza import Message as Stanza
    from slixmpp.xmlstream import ET

    from agents.stanza import message_xml, read_message, uses_form
    from xmpp_server.compat import metadata_of

    def wire(msg, **kw):
        return message_xml(msg, **kw).replace("<message ", '<message xmlns="jabber:client" ', 1)

    msg = make_message("b@localhost", None, performative=Performative.REQUEST, ontology="o", action="a")
    msg.sender, msg.thread = "a@localhost/s", "th"
    msg.set_metadata("note", 'quote " and <tag> & \'apostrophe\'')
    compact = wire(msg)
    assert "jabber:x:data" not in compact and compact.count("<acl ") == 1
    got = read_message(Stanza(xml=ET.fromstring(compact)))
    assert metadata_of(got) == metadata_of(msg) and got.thread == "th" and not uses_form(got)
    for odd in ({"two words": "v"}, {"k": "line\nbreak"}, {"xmlns": "urn:x"}, {"_thread_node": "t"}):
        other = make_message("b@localhost", None, performative=Performative.INFORM)
        other.sender, other.thread = "a@localhost", "th" if "_thread_node" in odd else None
        for k, v in odd.items():
            other.set_metadata(k, v)
        text = wire(other)
        assert "jabber:x:data" in text and "<acl " not in text
        back = read_message(Stanza(xml=ET.fromstring(text)))  # well-formed: parsed at all
        assert uses_form(back)
        if "_thread_node" not in odd:
            assert metadata_of(back) == metadata_of(other)
    assert "jabber:x:data" in wire(msg, form=True)


PLAIN_SPADE_CLIENT = """
import asyncio, json, sys
from spade.agent import Agent
from spade.behaviour import OneShotBehaviour
from spade.message import Message

jid, port, to = sys.argv[1], int(sys.argv[2]), sys.argv[3]

class Ask(OneShotBehaviour):
    async def run(self):
        msg = Message(to=to, body=json.dumps({"a": 2, "b": 3}), metadata={
            "performative": "request", "ontology": "test-math", "action": "add", "conversation_id": "plain-1"})
        await self.send(msg)
        got = []
        while not any(m.get("performative") == "inform" for m in got):
            reply = await self.receive(timeout=10)
            if reply is None:
                break
            got.append({**reply._metadata, "body": reply.body})  # no public accessor in SPADE 4.1.4
        print(json.dumps(got), flush=True)

async def main():
    agent = Agent(jid, "plain-pw", port=port, verify_security=False)
    await agent.start(auto_register=True)
    b = Ask()
    agent.add_behaviour(b)
    await b.join()
    await agent.stop()

asyncio.run(main())
"""


async def test_a_plain_spade_agent_gets_its_answers_in_its_own_form(xmpp_server, unique):
    """Interop over the wire: a plain SPADE agent (its own process, no patches of ours) asks one of
    ours; the answers come back in SPADE's form, so SPADE reads their metadata."""
    import subprocess
    import sys

    settings = xmpp_server.settings(force_xmpp=True)
    server = RappAgent(unique("calc"), settings)
    await server.start()
    responder = Responder("test-math", {"add": _add}, agree=True)
    server.activate("math", responder, responder.make_template())
    try:
        proc = await asyncio.to_thread(
            subprocess.run, [sys.executable, "-c", PLAIN_SPADE_CLIENT, settings.jid(unique("plain")),
                             str(settings.port), server.address], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr[-2000:]
        got = json.loads(proc.stdout.strip().splitlines()[-1])
        assert [m["performative"] for m in got] == ["agree", "inform"], got
        assert all(m["conversation_id"] == "plain-1" and m["action"] == "add" for m in got)
        assert json.loads(got[-1]["body"]) == {"total": 5}
    finally:
        await server.stop()


def test_handlers_tried_only_on_their_tag_match_as_before():
    """xmpp_server/compat.match_only_its_tag: on an agent's client, every handler matches exactly the
    stanzas its own matcher matches (message, chat error, presence, iq set/get/result)."""
    from slixmpp.xmlstream import ET

    from xmpp_server.compat import rapp_xmpp_client_class

    client = rapp_xmpp_client_class()("tags-a@localhost", "pw", False, True)
    client.register_plugin("xep_0030")
    iq = client.Iq(stype="get", sto="tags-a@localhost/r", sfrom="localhost")
    iq.enable("ping")
    stanzas = [ET.fromstring(x) for x in (
        '<message xmlns="jabber:client" to="tags-a@localhost" from="b@localhost"><body>hi</body></message>',
        '<message xmlns="jabber:client" type="error" from="b@localhost"><error type="cancel"/></message>',
        '<presence xmlns="jabber:client" from="b@localhost/r"/>',
        '<iq xmlns="jabber:client" type="set" id="r1"><query xmlns="jabber:iq:roster"/></iq>',
        '<iq xmlns="jabber:client" type="get" id="d1"><query xmlns="http://jabber.org/protocol/disco#info"/></iq>',
        '<iq xmlns="jabber:client" type="result" id="x1"/>')] + [iq.xml]
    handlers = client._XMLStream__handlers  # slixmpp keeps them private (pinned 1.12.0)
    filtered = [h for h in handlers if getattr(h, "matches_only_its_tag", False)]
    assert len(filtered) >= 10  # the iq, presence and message handlers of SPADE's plugins
    for xml in stanzas:
        stanza = client._build_stanza(xml)
        for h in filtered:
            assert h.match(stanza) == bool(h.unfiltered_match(stanza)), (h.name, xml.tag)
    assert sum(h.match(client._build_stanza(stanzas[0])) for h in handlers) == 1  # the chat handler only


def test_ids_are_unique_and_not_shared_with_a_forked_child():
    import os

    from ontology.acl import new_id

    ids = {new_id() for _ in range(5000)}
    assert len(ids) == 5000 and all(len(i) == 18 for i in ids)  # "c-" + 16 hex digits
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child's next ids must not be the parent's next ones
        os.write(write, " ".join(new_id() for _ in range(50)).encode())
        os._exit(0)
    os.close(write)
    child = set(os.read(read, 65536).decode().split())
    os.waitpid(pid, 0)
    assert len(child) == 50 and not child & {new_id() for _ in range(50)}
