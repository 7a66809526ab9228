"""Platform Agent messages: users and tokens, service discovery, Cloud Agent lifecycle.

Every service request carries a token (`ServiceRequest.token`); the Platform refuses a missing,
wrong or expired one before the service runs.
"""
from __future__ import annotations

from typing import Any

from pydantic import Field

from .registry import Action, Content, Done, action

ONTOLOGY = "platform"


class ServiceRequest(Action):
    """Base of every Platform service request."""

    token: str = ""


class TokenReply(Content):
    token: str
    expires_at: float  # unix time
    user: str


@action("register_user", ontology=ONTOLOGY, reply=Done, group="users")
class RegisterUser(Action):
    user: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    password: str = Field(min_length=1, max_length=256)


@action("login", ontology=ONTOLOGY, reply=TokenReply, group="users")
class Login(Action):
    user: str
    password: str
    ttl_s: float = Field(default=3600.0, gt=0, le=7 * 24 * 3600)


class ServiceInfo(Content):
    name: str
    group: str
    request_schema: dict[str, Any]
    reply_schema: dict[str, Any] | None = None


class ServiceList(Content):
    services: list[ServiceInfo]


@action("issue_app_token", ontology=ONTOLOGY, reply=TokenReply, group="users")
class IssueAppToken(ServiceRequest):
    """A token for one RApp run, limited to the services its manifest declares (the Core asks
    for it before starting the Dynamic Agent and hands it over instead of its own)."""

    rapp: str
    services: list[str]
    holder_jid: str  # the run's Dynamic Agent: the only JID the Platform accepts the token from
    ttl_s: float = Field(default=3600.0, gt=0, le=24 * 3600)


class TokenOwner(Content):
    user: str
    holder: str  # the only JID that may use the token
    rapp: str | None = None


@action("verify_token", ontology=ONTOLOGY, reply=TokenOwner, group="users")
class VerifyToken(Action):
    """The Store asks who holds a token that came with a download (answered to the Store only)."""

    token: str


@action("list_services", ontology=ONTOLOGY, reply=ServiceList, group="discovery", idempotent=True)
class ListServices(Action):
    in_group: str | None = None


class CloudAgentReply(Content):
    jid: str
    rapp: str
    version: str


@action("start_cloud_agent", ontology=ONTOLOGY, reply=CloudAgentReply, group="cloud")
class StartCloudAgent(ServiceRequest):
    """Start the run's Cloud Agent (the RApp's cloud part): once per run; the SDK's
    `self.cloud.start()`."""

    rapp: str
    version: str | None = None
    owner_jid: str = ""  # must be the sender (the Dynamic Agent the Cloud Agent lives and dies with)


@action("stop_cloud_agent", ontology=ONTOLOGY, reply=Done, group="cloud")
class StopCloudAgent(ServiceRequest):
    """Stop a Cloud Agent the sender owns."""

    jid: str


class Refused(Content):
    """One operation an agent refused a RApp run (told to its Core at the run's end)."""

    by: str  # the agent (or "sandbox") that refused it
    what: str  # the action or system call
    why: str = ""
    count: int = 1


class Released(Content):
    """The Cloud Agents are stopped; what the Platform refused the run (its Dynamic Agent and Cloud Agents)."""

    ok: bool = True
    refused: list[Refused] = Field(default_factory=list)


@action("release_cloud_agents", ontology=ONTOLOGY, reply=Released, group="cloud")
class ReleaseCloudAgents(ServiceRequest):
    """Stop every Cloud Agent that lives with this Dynamic Agent (sent by its Core on destroy); the
    reply lists what the Platform refused that run."""

    owner_jid: str


@action("cloud_ready", ontology=ONTOLOGY, reply=Done, group="cloud")
class CloudReady(Action):
    """Sent by a Cloud Agent once it serves requests."""

    jid: str


@action("cloud_agent_down", ontology=ONTOLOGY, reply=Done, group="cloud")
class CloudAgentDown(Action):
    """The Platform tells a Dynamic Agent its Cloud Agent's process ended unasked (notification).
    Where the manifest lets the Platform start it again once, under the same JID, two notices:
    `restarting` at once (calls in flight fail, new ones wait), then `restarted` once it serves
    (or neither flag: the restart failed and the Cloud Agent is lost)."""

    jid: str
    reason: str
    restarted: bool = False
    restarting: bool = False


@action("register_robot", ontology=ONTOLOGY, reply=Done, group="robots")
class RegisterRobot(Action):
    robot_id: str
    robot_type: str
    core_jid: str


class Pong(Content):
    user: str
    t: float


@action("ping", ontology=ONTOLOGY, reply=Pong, group="diagnostics", idempotent=True)
class Ping(ServiceRequest):
    """The cheapest service: checks the token and answers (round-trip measurements)."""
