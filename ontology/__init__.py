"""Message shapes of the RAPP agents: FIPA-ACL conventions and pydantic content models."""
from .acl import Performative, Protocol
from .registry import Action, Content, ContentError, Done, action, lookup, decode_request, encode
from .common import Reason

__all__ = [
    "Performative", "Protocol", "Action", "Content", "ContentError", "Done", "action", "lookup",
    "decode_request", "encode", "Reason",
]
