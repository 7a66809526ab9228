"""FIPA-ACL conventions on SPADE message metadata.

An ACL message is a SPADE message whose metadata carries the FIPA fields below and whose body is
the JSON of a pydantic model. Metadata values must be strings (on the wire: attributes of one element
between our agents, an XEP-0004 form to plain SPADE agents; agents/stanza.py).
On the wire, reply_with travels as the stanza id (agents/stanza.py); receivers see it in the metadata.
"""
from __future__ import annotations

import os
import threading
from enum import Enum

LANGUAGE = "json"


class Performative(str, Enum):
    REQUEST = "request"
    AGREE = "agree"
    REFUSE = "refuse"
    INFORM = "inform"
    FAILURE = "failure"
    NOT_UNDERSTOOD = "not-understood"
    CANCEL = "cancel"
    QUERY_REF = "query-ref"
    SUBSCRIBE = "subscribe"
    CONFIRM = "confirm"
    PROPAGATE = "propagate"


class Protocol(str, Enum):
    REQUEST = "fipa-request"
    QUERY = "fipa-query"
    SUBSCRIBE = "fipa-subscribe"
    NOTIFY = "rapp-notify"  # one-way typed notification (paper 003), no reply expected


# metadata keys
PERFORMATIVE = "performative"
ONTOLOGY = "ontology"
ACTION = "action"
CONVERSATION_ID = "conversation_id"
REPLY_WITH = "reply_with"
IN_REPLY_TO = "in_reply_to"
PROTOCOL = "protocol"
LANGUAGE_KEY = "language"
REPLY_BY = "reply_by"
# actions with feedback (the ROS action pattern on FIPA request): a request carrying FEEDBACK="1"
# asks for progress; the responder then sends informs carrying FEEDBACK="1" (an
# ontology.registry.Progress each) before its final answer; a `cancel` in the conversation stops
# the action, which then ends with failure(cancelled)
FEEDBACK = "feedback"

# performatives that open a conversation (the receiver must answer them)
OPENING = {Performative.REQUEST, Performative.QUERY_REF, Performative.SUBSCRIBE}
# answers that close a request (agree only advances it)
FINAL = {Performative.INFORM, Performative.FAILURE, Performative.REFUSE, Performative.NOT_UNDERSTOOD}
# performatives that may close or advance one (routed to the waiting initiator)
ANSWERS = {
    Performative.AGREE,
    Performative.REFUSE,
    Performative.INFORM,
    Performative.FAILURE,
    Performative.NOT_UNDERSTOOD,
    Performative.CONFIRM,
}


def new_id(prefix: str = "c") -> str:
    """64 random bits (unguessable: a reply is matched by its conversation id), drawn from a
    buffer of os.urandom: a uuid4 per id was a third of building a message."""
    with _random_lock:
        if len(_random) < 8:
            _random.extend(os.urandom(4096))
        chunk = _random[-8:]
        del _random[-8:]
    return f"{prefix}-{chunk.hex()}"


_random = bytearray()
_random_lock = threading.Lock()


def _after_fork() -> None:  # a forked child must not repeat its parent's ids (nor inherit a held lock)
    global _random_lock
    _random.clear()
    _random_lock = threading.Lock()


os.register_at_fork(after_in_child=_after_fork)
