"""Platform Agent: users and tokens, service discovery and dispatch, Cloud Agent lifecycle
(paper 000 sec. 5.3, fig. 6; paper 001 sec. 3).

Every service request carries a token; a missing, unknown or expired one is refused before the
service runs. Services are synchronous CPU work (agents/services) run in worker threads, so one
robot's request never stalls another's; past `max_pending` concurrent calls new ones are refused
with a reason rather than left unanswered.
"""
from __future__ import annotations

import asyncio
import itertools
import json
import logging
import secrets
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import ontology.services  # noqa: F401 - registers the service models
from ontology import platform as P
from ontology.registry import Done, actions

from .base import RappAgent
from .errors import Failure, Refusal, RequestError
from .process import AgentProcess, Limits
from .responder import Responder
from .store_client import download_package
from .store_repository import _check_password, hash_password

log = logging.getLogger("rapp.platform")
# what every RApp token may call besides the services its manifest declares
ALWAYS_ALLOWED = {"start_cloud_agent", "stop_cloud_agent", "ping", "list_services"}


@dataclass
class CloudSession:
    jid: str
    rapp: str
    version: str
    owner: str
    user: str
    process: AgentProcess
    ready: asyncio.Event = field(default_factory=asyncio.Event)


class PlatformAgent(RappAgent):
    def __init__(self, name: str = "platform", *, store: str = "store", settings=None,
                 workdir: str | Path | None = None, max_pending: int = 64,
                 limits: Limits = Limits(), services: dict | None = None, services_state=None):
        super().__init__(name, settings)
        from agents.services.context import ServiceState

        if services is None:
            from agents.services import SERVICES as services

        self.store = self.settings.jid(store)
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="rapp-platform-"))
        self.services = services
        self.state = services_state or ServiceState()
        self.users: dict[str, str] = {}  # user -> password hash
        self.tokens: dict[str, tuple[str, float]] = {}  # token -> (user, expires_at)
        self.scopes: dict[str, tuple[str, frozenset[str]]] = {}  # app token -> (rapp, services)
        self.robots: dict[str, P.RegisterRobot] = {}
        self.clouds: dict[str, CloudSession] = {}
        self.max_pending, self.pending = max_pending, 0
        self.limits = limits
        self.served = 0
        self._serial = itertools.count(1)

    async def setup(self) -> None:
        handlers = {"register_user": self.register_user, "login": self.login,
                    "list_services": self.list_services, "register_robot": self.register_robot,
                    "start_cloud_agent": self.start_cloud, "stop_cloud_agent": self.stop_cloud,
                    "release_cloud_agents": self.release_clouds, "cloud_ready": self.cloud_ready,
                    "ping": self.ping, "issue_app_token": self.issue_app_token}
        for name in self.services:
            handlers[name] = self.run_service
        responder = Responder(P.ONTOLOGY, handlers, check=self._check_token)
        self.activate("platform-service", responder, responder.make_template())

    async def stop(self) -> None:
        for cloud in list(self.clouds.values()):
            await self._kill_cloud(cloud, "platform stopping")
        await super().stop()

    # -- users and tokens ---------------------------------------------------------------------
    def _check_token(self, req, ctx) -> None:
        if not isinstance(req, P.ServiceRequest):
            return
        ctx.user = self.user_of(req.token)
        scope = self.scopes.get(req.token)
        if scope is not None:
            rapp, allowed = scope
            if req.action_name == "issue_app_token":
                raise Refusal("a RApp token cannot issue tokens", "permission")
            if req.action_name not in allowed and req.action_name not in ALWAYS_ALLOWED:
                raise Refusal(f"{rapp} did not declare the service {req.action_name!r} in its manifest",
                              "permission")

    def user_of(self, token: str) -> str:
        if not token:
            raise Refusal("missing token: log in first and send the token with every call", "no-token")
        entry = self.tokens.get(token)
        if entry is None:
            raise Refusal("unknown token", "bad-token")
        user, expires = entry
        if time.time() > expires:
            self.tokens.pop(token, None)
            self.scopes.pop(token, None)
            raise Refusal("token expired: log in again", "expired-token")
        return user

    async def register_user(self, req: P.RegisterUser, ctx) -> Done:
        if req.user in self.users:
            raise Refusal(f"user {req.user!r} already registered", "duplicate")
        self.users[req.user] = await asyncio.to_thread(hash_password, req.password)
        return Done()

    async def login(self, req: P.Login, ctx) -> P.TokenReply:
        stored = self.users.get(req.user)
        if stored is None or not await asyncio.to_thread(_check_password, req.password, stored):
            raise Refusal("unknown user or wrong password", "bad-login")
        token = secrets.token_urlsafe(24)
        expires = time.time() + req.ttl_s
        self.tokens[token] = (req.user, expires)
        return P.TokenReply(token=token, expires_at=expires, user=req.user)

    async def issue_app_token(self, req: P.IssueAppToken, ctx) -> P.TokenReply:
        unknown = sorted(set(req.services) - set(actions(P.ONTOLOGY)))
        if unknown:
            raise Refusal(f"{req.rapp} declares unknown services: {', '.join(unknown)}", "unknown-service")
        token = secrets.token_urlsafe(24)
        expires = min(time.time() + req.ttl_s, self.tokens[req.token][1])
        self.tokens[token] = (ctx.user, expires)
        self.scopes[token] = (req.rapp, frozenset(req.services))
        return P.TokenReply(token=token, expires_at=expires, user=ctx.user)

    async def register_robot(self, req: P.RegisterRobot, ctx) -> Done:
        self.robots[req.robot_id] = req
        self.record_structure("register", robot=req.robot_id, robot_type=req.robot_type,
                              by=ctx.sender, at="platform")
        return Done()

    async def list_services(self, req: P.ListServices, ctx) -> P.ServiceList:
        out = []
        for name, model in sorted(actions(P.ONTOLOGY).items()):
            if req.in_group and model.group != req.in_group:
                continue
            out.append(P.ServiceInfo(name=name, group=model.group, request_schema=model.model_json_schema(),
                                     reply_schema=model.reply_model.model_json_schema() if model.reply_model else None))
        return P.ServiceList(services=out)

    async def ping(self, req: P.Ping, ctx) -> P.Pong:
        return P.Pong(user=ctx.user, t=time.time())

    # -- services -------------------------------------------------------------------------------
    async def run_service(self, req, ctx):
        from agents.services.context import ServiceContext
        from agents.services.errors import ServiceError

        if self.pending >= self.max_pending:
            raise Refusal(f"platform busy: {self.pending} calls in progress, retry shortly", "busy")
        spec = self.services[req.action_name]
        self.pending += 1
        try:
            return await asyncio.to_thread(spec.run, req, ServiceContext(user=ctx.user, state=self.state))
        except ServiceError as e:
            raise Failure(str(getattr(e, "reason", e)), getattr(e, "code", "service-error")) from None
        finally:
            self.pending -= 1
            self.served += 1

    # -- Cloud Agents -----------------------------------------------------------------------------
    async def start_cloud(self, req: P.StartCloudAgent, ctx) -> P.CloudAgentReply:
        owner = req.owner_jid or ctx.sender
        try:
            info, data = await download_package(self, self.store, req.rapp, req.version)
        except RequestError as e:
            raise Failure(f"cannot fetch {req.rapp} from the Store: {e.reason}", "store") from None
        if not info.manifest.get("cloud_entry_point"):
            raise Refusal(f"{req.rapp} has no Cloud Agent part", "no-cloud-part")
        from rapps.package import unpack_package

        n = next(self._serial)
        name = f"cloud-{info.name}-{n}".replace("_", "-")
        workdir = self.workdir / f"{n:04d}-{info.name}"
        pkg_dir = workdir / "package"
        await asyncio.to_thread(unpack_package, data, pkg_dir)
        spec = {"kind": "cloud", "name": name, "package_dir": str(pkg_dir), "owner": owner,
                "platform": self.address, "token": req.token}
        workdir.joinpath("spec.json").write_text(json.dumps(spec))
        proc = AgentProcess(name, "agents.runtime", [str(workdir / "spec.json")], workdir,
                            env=self.settings.to_env(), limits=self.limits)
        session = CloudSession(jid=self.settings.jid(name), rapp=info.name, version=info.version,
                               owner=owner, user=ctx.user, process=proc)
        self.clouds[session.jid] = session
        await proc.start()
        self.record_structure("cloud-spawn", cloud=session.jid, rapp=info.name, owner=owner, pid=proc.pid)
        waiter = asyncio.create_task(session.ready.wait())
        exited = asyncio.create_task(proc.wait())
        done, _ = await asyncio.wait({waiter, exited}, timeout=self.settings.start_timeout + 10,
                                     return_when=asyncio.FIRST_COMPLETED)
        waiter.cancel()
        if not session.ready.is_set():
            exited.cancel()
            await self._kill_cloud(session, "did not start")
            raise Failure(f"Cloud Agent of {req.rapp} did not start: {proc.stderr_tail(500)}", "cloud-start")
        exited.add_done_callback(lambda _: self.clouds.get(session.jid) and
                                 asyncio.ensure_future(self._kill_cloud(session, "process exited")))
        return P.CloudAgentReply(jid=session.jid, rapp=info.name, version=info.version)

    async def cloud_ready(self, req: P.CloudReady, ctx) -> Done:
        session = self.clouds.get(ctx.sender)
        if session is None:
            raise Refusal(f"{ctx.sender} is not a Cloud Agent of this Platform", "unknown-cloud")
        session.ready.set()
        return Done()

    async def stop_cloud(self, req: P.StopCloudAgent, ctx) -> Done:
        session = self.clouds.get(req.jid)
        if session is None:
            raise Refusal(f"no Cloud Agent {req.jid}", "not_found")
        if ctx.sender != session.owner and ctx.user != session.user:
            raise Refusal(f"{ctx.sender} does not own {req.jid}", "forbidden")
        await self._kill_cloud(session, f"stopped by {ctx.sender}")
        return Done()

    async def release_clouds(self, req: P.ReleaseCloudAgents, ctx) -> Done:
        for session in [c for c in self.clouds.values() if c.owner == req.owner_jid]:
            if ctx.user != session.user:
                raise Refusal(f"{req.owner_jid}'s Cloud Agents belong to another user", "forbidden")
            await self._kill_cloud(session, f"owner {req.owner_jid} ended")
        return Done()

    async def _kill_cloud(self, session: CloudSession, reason: str) -> None:
        if self.clouds.pop(session.jid, None) is None:
            return
        code = await session.process.stop(grace=1.0)
        self.record_structure("cloud-destroy", cloud=session.jid, rapp=session.rapp, reason=reason,
                              exit_code=code)
        shutil.rmtree(session.process.workdir / "package", ignore_errors=True)
