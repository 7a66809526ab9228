"""Errors an initiator sees when a FIPA-Request does not end in inform."""
from __future__ import annotations

from ontology.errors import ErrorCode


class AgentStartError(RuntimeError):
    """The agent could not log in to the XMPP server in time."""


class RequestError(RuntimeError):
    def __init__(self, reason: str, *, code: str = ErrorCode.ERROR, peer: str = "", action: str = ""):
        super().__init__(reason)
        self.reason, self.code, self.peer, self.action = reason, code, peer, action


class RequestRefused(RequestError):
    """The responder answered refuse (e.g. not the current supervisor, wrong token)."""


class RequestFailed(RequestError):
    """The responder agreed or tried, then answered failure."""


class CloudAgentLost(RequestFailed):
    """The RApp's Cloud Agent died (code "cloud-lost") or was restarted by the Platform
    ("cloud-restarted": a call in flight was lost, a new call may succeed)."""


class NotUnderstood(RequestError):
    """The responder could not parse or does not know the action."""


class RequestTimeout(RequestError):
    """No final answer within the time limit."""


class Refusal(Exception):
    """Raised by a responder handler to answer `refuse` with this reason."""

    def __init__(self, reason: str, code: str = ErrorCode.REFUSED):
        super().__init__(reason)
        self.reason, self.code = reason, code


class Failure(Exception):
    """Raised by a responder handler to answer `failure` with this reason."""

    def __init__(self, reason: str, code: str = ErrorCode.FAILED):
        super().__init__(reason)
        self.reason, self.code = reason, code
