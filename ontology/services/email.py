"""E-mail services against the user's mailbox."""
from __future__ import annotations

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, Done, action

GROUP = "email"


class EmailMessage(Content):
    id: str = ""
    sender: str
    recipients: list[str]
    subject: str = ""
    body: str = ""
    date: str = ""
    unread: bool = True


@action("email_send", ontology="platform", reply=Done, group=GROUP)
class EmailSend(ServiceRequest):
    """Delivered to each recipient's local mailbox (recipient = user name or user@anything)."""

    recipients: list[str] = Field(min_length=1)
    subject: str = Field(default="", max_length=500)
    body: str = Field(default="", max_length=100_000)


class EmailList(Content):
    messages: list[EmailMessage]


@action("email_fetch", ontology="platform", reply=EmailList, group=GROUP)
class EmailFetch(ServiceRequest):
    """The user's messages from their local mailbox, oldest first."""

    unread_only: bool = False
    max_messages: int = Field(default=20, ge=1, le=500)
    mark_read: bool = True
