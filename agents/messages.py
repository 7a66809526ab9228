"""Building and reading ACL messages (SPADE Message + FIPA metadata + pydantic content)."""
from __future__ import annotations

from typing import NamedTuple

from spade.message import Message

from ontology import acl
from ontology.acl import Performative
from ontology.registry import Action, Content, encode
from xmpp_server.compat import metadata_of


def make_message(to: str, content: Content | None, *, performative: Performative | str,
                 ontology: str = "", action: str = "", conversation_id: str | None = None,
                 in_reply_to: str | None = None, protocol: str = acl.Protocol.REQUEST.value,
                 feedback: bool = False) -> Message:
    if isinstance(content, Action):
        ontology = ontology or content.ontology_name
        action = action or content.action_name
    # language (always json) and the default protocol (fipa-request) are implied, not sent: every
    # metadata field is two more XML elements the server and both ends parse (AclInfo fills them in)
    meta = {
        acl.PERFORMATIVE: Performative(performative).value,
        acl.CONVERSATION_ID: conversation_id or acl.new_id(),
        acl.REPLY_WITH: acl.new_id("m"),
    }
    if protocol != acl.Protocol.REQUEST.value:
        meta[acl.PROTOCOL] = protocol
    if ontology:
        meta[acl.ONTOLOGY] = ontology
    if action:
        meta[acl.ACTION] = action
    if in_reply_to:
        meta[acl.IN_REPLY_TO] = in_reply_to
    if feedback:
        meta[acl.FEEDBACK] = "1"
    # no XMPP thread: it would only repeat the conversation id on the wire
    return Message(to=str(to), body=encode(content), metadata=meta)


def reply_to(msg: Message, content: Content | None, performative: Performative | str,
             feedback: bool = False) -> Message:
    """A reply in the same conversation, same ontology and action, addressed to the sender
    (`feedback`: a progress inform of an action with feedback, not its final answer)."""
    info = AclInfo.of(msg)
    return make_message(
        str(msg.sender), content, performative=performative, ontology=info.ontology,
        action=info.action, conversation_id=info.conversation_id or None,
        in_reply_to=info.reply_with or None, protocol=info.protocol or acl.Protocol.REQUEST.value,
        feedback=feedback,
    )


def is_feedback(msg: Message) -> bool:
    return msg.get_metadata(acl.FEEDBACK) == "1"


class AclInfo(NamedTuple):
    """A message's FIPA fields ("" when absent). A named tuple: one is built per message and side,
    and a frozen dataclass's __init__ cost three times as much."""
    performative: str
    ontology: str
    action: str
    conversation_id: str
    reply_with: str
    in_reply_to: str
    protocol: str

    @classmethod
    def of(cls, msg: Message) -> "AclInfo":
        g = metadata_of(msg).get  # SPADE's get_metadata, without a call per field
        performative = g(acl.PERFORMATIVE) or ""
        return cls(performative, g(acl.ONTOLOGY) or "", g(acl.ACTION) or "",
                   g(acl.CONVERSATION_ID) or msg.thread or "", g(acl.REPLY_WITH) or "",
                   g(acl.IN_REPLY_TO) or "",
                   g(acl.PROTOCOL) or (acl.Protocol.REQUEST.value if performative else ""))

    @property
    def language(self) -> str:
        return acl.LANGUAGE if self.performative else ""

    @property
    def is_acl(self) -> bool:
        return bool(self.performative)


def copy_message(msg: Message) -> Message:
    """SPADE's in-process path hands the sender's own object over; receivers get a copy."""
    return msg.make_reply().make_reply()  # make_reply swaps to/sender and copies metadata


def bare(jid) -> str:
    s = str(jid)
    return s.split("/", 1)[0]
