"""Serialise a SPADE Message to its XMPP stanza text directly.

SPADE's Message.prepare builds the metadata as an XEP-0004 form through slixmpp's stanza objects,
which costs ~350 µs a message (measured in bench/); the same XML written as text costs ~15 µs.
The output is exactly what spade.message.Message.from_node parses.
"""
from __future__ import annotations

import uuid
from xml.sax.saxutils import escape, quoteattr

from spade.message import SPADE_X_METADATA, Message


def message_xml(msg: Message) -> str:
    parts = [f"<message to={quoteattr(str(msg.to))} from={quoteattr(str(msg.sender))} type=\"chat\" "
             f"id=\"{uuid.uuid4().hex}\">"]
    if msg.body is not None:
        parts.append(f"<body>{escape(msg.body)}</body>")
    meta = msg._metadata  # SPADE keeps metadata here; there is no public accessor in 4.1.4
    if meta:
        parts.append(f"<x xmlns=\"jabber:x:data\" type=\"form\"><title>{SPADE_X_METADATA}</title>")
        for key, value in meta.items():
            parts.append(f"<field var={quoteattr(key)} type=\"text-single\"><value>{escape(value)}</value></field>")
        if msg.thread:
            parts.append(f"<field var=\"_thread_node\" type=\"text-single\"><value>{escape(msg.thread)}</value></field>")
        parts.append("</x>")
    parts.append("</message>")
    return "".join(parts)
