"""Serialise a SPADE Message to its XMPP stanza text directly, and read one back.

Two wire forms of the metadata, both read always:
- compact (what our agents send each other): one element, the metadata as its attributes,
  `<acl xmlns="urn:rapp:acl:1" performative="inform" conversation_id="c-.." .../>`. SPADE's form
  is two elements per field plus the form and its title; parsing them was most of a message's
  receive cost, and the server parses every element too (figures: docs/spade-pitfalls.md);
- SPADE's XEP-0004 form (`jabber:x:data`, title spade:x:metadata), what spade.message.Message.
  from_node reads: sent to a peer that sent us that form (a plain SPADE agent), so such a peer
  gets its answers in its own dialect (`message_xml(msg, form=True)`).
SPADE's Message.prepare builds the form through slixmpp's stanza objects, twenty times the cost of
writing the XML as text (docs/spade-pitfalls.md). Form fields carry no `type` (text-single is XEP-0004's default).
In both forms FIPA's reply-with travels as the stanza id, which every stanza has anyway
(`read_message` puts it back into the metadata).
"""
from __future__ import annotations

import re
import uuid
from xml.sax.saxutils import escape, quoteattr

from spade.message import SPADE_X_METADATA, Message

from ontology import acl
from xmpp_server.compat import metadata_of

_XDATA = "{jabber:x:data}"
_FORM, _TITLE, _FIELD, _VALUE = _XDATA + "x", _XDATA + "title", _XDATA + "field", _XDATA + "value"
_MARKUP = re.compile(r"[&<>\"]")  # what escaping changes; most ids, names and JSON keys have none
ACL_NS = "urn:rapp:acl:1"
_ACL = "{%s}acl" % ACL_NS
# a metadata key that can be an attribute name (not one XML reserves: "xmlns" would clash with ours)
_NAME = re.compile(r"(?![Xx][Mm][Ll])[A-Za-z_][A-Za-z0-9_.-]*\Z")
_CONTROL = re.compile(r"[\t\n\r]")  # attribute values normalise these: such a value goes in a form


def _text(value: str) -> str:
    return escape(value) if _MARKUP.search(value) else value


def _attr(value: str) -> str:
    return quoteattr(value) if _MARKUP.search(value) or "'" in value else f'"{value}"'


def message_xml(msg: Message, form: bool = False) -> str:
    """The stanza of `msg`; its metadata compact unless `form` (or a key or value that an attribute
    cannot carry as it is)."""
    meta = metadata_of(msg)
    stanza_id = meta.get(acl.REPLY_WITH) or uuid.uuid4().hex
    parts = [f"<message to={_attr(str(msg.to))} from={_attr(str(msg.sender))} type=\"chat\" "
             f"id={_attr(stanza_id)}>"]
    if msg.body is not None:
        parts.append(f"<body>{_text(msg.body)}</body>")
    fields = [(k, v) for k, v in meta.items() if k != acl.REPLY_WITH]
    if msg.thread:
        fields.append(("_thread_node", msg.thread))
    if (fields and not form and all(_NAME.match(k) and not _CONTROL.search(v) for k, v in fields)
            and len({k for k, _ in fields}) == len(fields)):  # a key "_thread_node" beside a thread
        parts.append("<acl xmlns=\"%s\" %s/>" % (ACL_NS, " ".join(f"{k}={_attr(v)}" for k, v in fields)))
    elif fields:
        parts.append(f"<x xmlns=\"jabber:x:data\" type=\"form\"><title>{SPADE_X_METADATA}</title>")
        parts.extend(f"<field var={_attr(k)}><value>{_text(v)}</value></field>" for k, v in fields)
        parts.append("</x>")
    parts.append("</message>")
    return "".join(parts)


def read_message(node) -> Message:
    """The SPADE Message of a received slixmpp message stanza; an ACL message's stanza id is its
    reply-with. Reads the stanza's XML element directly: the body, the compact metadata or what
    spade.message.Message.from_node reads (the spade:x:metadata form, its _thread_node), without
    slixmpp's per-item plugin lookups (a third of a message's receive cost in bench/messages.py).
    `uses_form(msg)` tells whether the metadata came as SPADE's form."""
    xml = node.xml
    body_tag = "{%s}body" % node.namespace
    body, meta, thread, form = None, {}, None, False
    for child in xml:  # one pass over the children; ElementPath's find/iterfind cost more
        if child.tag == body_tag:
            if body is None:
                body = child.text or ""
        elif child.tag == _ACL:
            meta.update(child.attrib)
            thread = meta.pop("_thread_node", thread)
        elif child.tag == _FORM and any(e.tag == _TITLE and e.text == SPADE_X_METADATA for e in child):
            for field in child:
                value = field.find(_VALUE) if field.tag == _FIELD else None
                if value is None or value.text is None:
                    continue
                if field.get("var") == "_thread_node":
                    thread = value.text
                else:
                    meta[field.get("var")] = value.text
            form = True
    stanza_id = xml.get("id")
    if stanza_id and acl.PERFORMATIVE in meta and acl.REPLY_WITH not in meta:
        meta[acl.REPLY_WITH] = stanza_id
    msg = Message(to=xml.get("to"), sender=xml.get("from"), body=body, thread=thread, metadata=meta)
    if form:
        msg.spade_form = True  # read by uses_form: the sender speaks SPADE's form
    return msg


def uses_form(msg: Message) -> bool:
    return getattr(msg, "spade_form", False)
