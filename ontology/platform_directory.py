"""Messages between several Platform agents of one domain and their clients (the primary's
directory of Platform agents: agents/platform_directory.py)."""
from __future__ import annotations

from .registry import Action, Content, Done, action

ONTOLOGY = "platform-directory"


class PlatformEntry(Content):
    jid: str
    services: list[str]
    capacity: int  # worker processes
    outstanding: int  # calls running when it last reported
    primary: bool = False
    age_s: float = 0.0  # since that report


class PlatformList(Content):
    platforms: list[PlatformEntry]


@action("platform_report", ontology=ONTOLOGY, reply=Done, group="directory")
class PlatformReport(Action):
    """A replica's registration and heartbeat (every REPORT_S) to its primary."""

    services: list[str]
    capacity: int = 1
    outstanding: int = 0
    served: int = 0


@action("list_platforms", ontology=ONTOLOGY, reply=PlatformList, group="directory", idempotent=True)
class ListPlatforms(Action):
    """The Platform agents serving this domain (the primary first), for a holder of a valid token."""

    token: str = ""


class TokenRecord(Content):
    user: str
    expires_at: float
    holder: str
    rapp: str | None = None
    services: list[str] | None = None
    issuer: str | None = None


@action("lookup_token", ontology=ONTOLOGY, reply=TokenRecord, group="directory", idempotent=True)
class LookupToken(Action):
    """A replica asks the primary what a token grants (answered to named replicas only)."""

    token: str


@action("token_revoked", ontology=ONTOLOGY, reply=Done, group="directory")
class TokenRevoked(Action):
    """The primary tells its replicas a token is gone (SHA-256 of the token, never the token)."""

    digest: str
