"""Platform Agent: users and tokens, service discovery and dispatch, Cloud Agent lifecycle
(paper 000 sec. 5.3, fig. 6; paper 001 sec. 3).

Its behaviour is fig. 6's FSM (agents/platform_fsm.py): s0 -> s1 for the agent, and one pass
s1 -> s2 register | s3 interpret | s4 service | s5 create a_cloud | s6 destroy a_cloud -> s1 per
request, served side by side by the responders.

Every service request carries a token; a missing, unknown or expired one is refused before the
service runs. Services are synchronous work (agents/services): the CPU-bound ones (the pooled
column of agents/services/registry.py: vision, hazard checks, speech, path planning) run in the
Platform's worker processes (agents/services/pool.py, one per core, `service_workers=0`: in threads
as before), the cheap and stateful ones in worker threads, so one robot's request never stalls
another's and none runs on the event loop; past `max_pending` concurrent calls new ones are refused
with a reason rather than left unanswered.

Several Platform agents can serve one domain (agents/platform_directory.py, docs/deployment.md):
the primary (`replicas=[names]`) keeps users, tokens, Cloud Agents and every stateful service; a
replica (`primary=name`) serves the stateless CPU-bound services, verifies tokens with the primary
and reports its load to it; clients choose among them by load.
"""
from __future__ import annotations

import asyncio
import itertools
import logging
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import ontology.services  # noqa: F401 - registers the service models
from ontology.spawn import SpawnSpec
from ontology import platform as P
from ontology.registry import Done, actions
from ontology.errors import ErrorCode
from behaviours import BehaviourHost

from . import platform_directory as D
from .base import RappAgent
from .crash_box import BOX_NAME, keep_crash_input
from .errors import Failure, Refusal, RequestError, RequestRefused
from .process import AgentProcess, InProcessAgent, Limits, check_spawn_mode, spawn_agent, sweep_run_dirs
from .runtime import WARM_EXTRA_IMPORTS
from .responder import Responder
from .passes import run_pass
from .platform_fsm import CREATE_CLOUD, build_platform_fsm, build_request_fsm, route
from .store_client import download_package
from .identity import EphemeralAccounts, Identity, is_rapp_account, trace_refusal
from .messages import bare
from .platform_users import DirectoryError, TokenInfo, UserDirectory
from .sandbox import Sandbox
from .warm_pool import WarmPool

log = logging.getLogger("rapp.platform")
# once serving, a Cloud Agent in a process of its own (RApp code, its OpenCV work included) yields
# the CPU to the Platform's services and to Cloud Agents still starting: the Platform is shared by
# every robot, a Cloud Agent is one owner's RApp. Set for the process's threads and its session's
# scheduling group (agents/priority.py: the threads' nice alone does nothing across sessions); each
# Cloud Agent is a group of its own, so many of them add up against the Platform, hence +10, not +5
# (the fleet's service p95 with each: bench/RESULTS.md, "Full run, 2026-11-26"). An in-process one
# leaves its host alone.
CLOUD_NICE = 10
# what every RApp token may call besides the services its manifest declares
ALWAYS_ALLOWED = {"start_cloud_agent", "stop_cloud_agent", "ping", "list_services"}
# one Cloud Agent per run; a start that failed (30 s without "ready" on a loaded host) may be tried
# again, a few times, so a retry is not refused but a RApp cannot spawn processes without end
CLOUD_START_ATTEMPTS = 3


@dataclass
class CloudClaim:
    """What one run (a Dynamic Agent) did with its right to a Cloud Agent."""
    attempts: int = 0
    starting: bool = False
    started: bool = False


@dataclass
class CloudSession:
    jid: str
    rapp: str
    version: str
    owner: str
    user: str
    process: AgentProcess | InProcessAgent
    account: Identity
    supervisor: str | None  # the Core that issued the owner's app token
    token: str  # the Cloud Agent's own token (revoked with it)
    ready: asyncio.Event = field(default_factory=asyncio.Event)
    restartable: bool = False
    restarted: bool = False
    watcher: asyncio.Task | None = None


class PlatformAgent(RappAgent):
    def __init__(self, name: str = "platform", *, store: str = "store", settings=None,
                 workdir: str | Path | None = None, max_pending: int = 64,
                 limits: Limits = Limits(), services: dict | None = None, services_state=None,
                 data_dir: str | Path | None = None, sandbox: Sandbox | None = None,
                 cloud_mode: str = "process", warm_workers: int = 1, service_workers: int | None = None,
                 primary: str | None = None, replicas=(), warm_imports: tuple[str, ...] = WARM_EXTRA_IMPORTS,
                 cloud_nice: int = CLOUD_NICE, warm_hold_running: bool = False):
        super().__init__(name, settings)
        self.cloud_mode = check_spawn_mode(cloud_mode, "cloud_mode")
        if not isinstance(cloud_nice, int) or not 0 <= cloud_nice <= 19:
            raise ValueError(f"cloud_nice must be a whole number 0..19, not {cloud_nice!r}")
        self.cloud_nice = cloud_nice  # nice steps a serving Cloud Agent runs below this Platform
        from agents.services.context import ServiceState

        if services is None:
            from agents.services import SERVICES as services

        self.store = self.settings.jid(store)
        self._own_workdir = workdir is None  # a temporary one: removed whole at stop
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="rapp-platform-"))
        self.services = services
        # users and tokens survive a restart when data_dir is kept (SQLite, 0600)
        self.data_dir = Path(data_dir) if data_dir else None
        # per-user service data (maps, homes, learned models, history, marks; agents/services/saved.py)
        # kept in data_dir too; without one, in memory and files in the Platform's own work directory
        self._own_state = services_state is None
        self.state = services_state or (ServiceState.keeping(self.data_dir) if self.data_dir
                                        else ServiceState(work_dir=self.workdir / "services"))
        self.directory = UserDirectory(self.data_dir / "users.db" if self.data_dir else None)
        self._tokens: dict[str, TokenInfo] = {}  # cache of the directory's answers
        self.accounts = EphemeralAccounts(self.settings, owner=name)
        self.sandbox = sandbox or Sandbox()
        self.robots: dict[str, P.RegisterRobot] = {}
        self._cloud_runs: dict[str, CloudClaim] = {}  # per Dynamic Agent: its Cloud Agent (one per run)
        self._refused: dict[str, list[P.Refused]] = {}  # run (Dynamic Agent) -> what was refused it
        self.clouds: dict[str, CloudSession] = {}
        self._cleanups: set[asyncio.Task] = set()  # stopped Cloud Agents' accounts and directories
        self.max_pending, self.pending = max_pending, 0
        self.limits = limits
        # Cloud Agent processes started ahead of time (agents/warm_pool.py); 0: each starts cold
        # Cloud parts compute: numpy, cv2, scipy imported ahead (`warm_imports`, and what the builder adds)
        # each logged in as a Cloud Agent of its own while idle (an account it registers itself): a
        # start costs no login
        self.warm_pool = WarmPool(self.workdir, self.settings, size=warm_workers, limits=limits, sandbox=self.sandbox,
                                  preload=warm_imports, login=self._worker_account,
                                  forget=lambda ident: self.accounts.delete(ident.name, ident.password),
                                  hold_running=warm_hold_running)
        self._pool_started = False
        self.served = 0
        self._serial = itertools.count(1)
        # CPU-bound services in worker processes (None: one per core; 0: threads, as before)
        from agents.services.pool import ServicePool

        self.service_pool = ServicePool(service_workers, name=name) if service_workers != 0 else None
        self.capacity = self.service_pool.size if self.service_pool else 1
        # several Platform agents per domain: a replica names its primary, a primary its replicas
        self.primary = self.settings.jid(primary) if primary else None
        self.platforms = D.PlatformDirectory({self.settings.jid(r) for r in replicas})
        self._remote_tokens: dict[str, tuple[TokenInfo, float]] = {}  # replica: digest -> (info, fetched)
        self._reporter: asyncio.Task | None = None

    async def setup(self) -> None:
        if self.service_pool is not None:
            self.service_pool.start()  # workers fork in the background
        if self.primary is not None:
            self._setup_replica()
        else:
            await asyncio.to_thread(sweep_run_dirs, self.workdir)  # what a crash left behind
            self._handlers = {"register_user": self.register_user, "login": self.login,
                              "list_services": self.list_services, "register_robot": self.register_robot,
                              "stop_cloud_agent": self.stop_cloud,
                              "release_cloud_agents": self.release_clouds, "cloud_ready": self.cloud_ready,
                              "ping": self.ping, "issue_app_token": self.issue_app_token,
                              "verify_token": self.verify_token, "platform_report": self.platform_report,
                              "list_platforms": self.list_platforms, "lookup_token": self.lookup_token}
            for name in self.services:
                self._handlers[name] = self.run_service
            # every request is one pass of fig. 6's request FSM (agents/platform_fsm.py), side by side
            served = set(self._handlers) | CREATE_CLOUD  # s5's steps are the Platform's own (cloud_*)
            responder = Responder(P.ONTOLOGY, {name: self._pass for name in actions(P.ONTOLOGY) if name in served},
                                  check=self._check_token)
            self.activate("platform-service", responder, responder.make_template())
            directory = Responder(D.ONTOLOGY, {name: self._pass for name in
                                               ("platform_report", "list_platforms", "lookup_token")})
            self.activate("platform-directory", directory, directory.make_template())
        self.activate("platform-fsm", BehaviourHost(build_platform_fsm(), {}))  # fig. 6: s0 -> s1

    def platform_init(self) -> None:
        """s0 of fig. 6: what a crashed earlier run left of the Cloud Agents' accounts goes."""
        if self.primary is None:
            self._sweeper = asyncio.create_task(self._sweep_accounts(self.accounts.pending()))

    async def _pass(self, req, ctx):
        """One request through fig. 6's states (agents/platform_fsm.py): s1 -> sX -> s1."""
        state = route(req.action_name, by_core=ctx.token is not None and ctx.token.services is None)
        memory = {"action": req.action_name, "request": req, "ctx": ctx}
        try:
            return await run_pass(self, build_request_fsm(state), memory, ctx.info.conversation_id)
        finally:
            if memory.get("admitted"):  # admitted (s4), never executed: a cancel came between
                self.pending -= 1
                self.served += 1
            if "claim" in memory:  # s5 ended, started or not: a failed start may be tried again
                memory["claim"].starting = False

    async def serve_request(self, memory: dict):
        """The step of s2, s3, s6 (and s4 for what is no pooled service): the action's handler."""
        return await self._handlers[memory["action"]](memory["request"], memory["ctx"])

    def _setup_replica(self) -> None:
        """Only the stateless services; everything else is the primary's (refused with its name, on
        arrival: it never enters fig. 6's states here)."""
        self._handlers = {"ping": self.ping, "list_services": self.list_services,
                          "token_revoked": self.token_revoked}
        self._handlers.update({name: self.run_service for name in D.REPLICATED if name in self.services})
        handlers = {name: self.primary_only for name in actions(P.ONTOLOGY)}
        handlers.update({name: self._pass for name in self._handlers if name != "token_revoked"})
        responder = Responder(P.ONTOLOGY, handlers, check=self._check_token)
        self.activate("platform-service", responder, responder.make_template())
        directory = Responder(D.ONTOLOGY, {"token_revoked": self._pass})
        self.activate("platform-directory", directory, directory.make_template())
        self._reporter = asyncio.create_task(self._report_loop())

    async def stop(self) -> None:
        if self._reporter is not None:
            self._reporter.cancel()
        if self.service_pool is not None:
            await asyncio.to_thread(self.service_pool.close)  # workers killed
        await self.warm_pool.close()  # idle workers killed and reaped
        for cloud in list(self.clouds.values()):
            await self._kill_cloud(cloud, "platform stopping")
        if self._cleanups:  # an account not deleted by then stays in the ledger for the next start
            await asyncio.wait(list(self._cleanups), timeout=5.0)
        try:  # prepared, unused accounts (any left stay in the ledger for the next start's sweep)
            await asyncio.wait_for(self.accounts.close(), 10.0)
        except asyncio.TimeoutError:
            log.warning("prepared Cloud Agent accounts not all deleted; the next start sweeps them")
        await super().stop()
        self.directory.close()
        if self._own_state:
            self.state.close()
        await asyncio.to_thread(sweep_run_dirs, self.workdir, self._own_workdir)

    async def _sweep_accounts(self, leftovers: dict[str, str]) -> None:
        """Delete the Cloud Agents' accounts a crashed earlier run of this Platform left behind."""
        gone = await self.accounts.sweep(leftovers)
        if gone:
            self.record_structure("accounts-swept", accounts=gone)

    # -- users and tokens ---------------------------------------------------------------------
    async def _check_token(self, req, ctx) -> None:
        """Every service request carries a token, accepted only from the JID it was issued to
        (the server-authenticated sender): a token read from a trace or a log is worthless."""
        if not isinstance(req, P.ServiceRequest):
            return
        info = await self.token_info(req.token)
        if info.holder != ctx.sender:
            raise Refusal(f"this token was issued to another agent, not to {ctx.sender}", ErrorCode.BAD_TOKEN)
        ctx.user, ctx.token = info.user, info
        if info.services is not None:
            if req.action_name == "issue_app_token":
                raise Refusal("a RApp token cannot issue tokens", ErrorCode.PERMISSION)
            if req.action_name not in info.services and req.action_name not in ALWAYS_ALLOWED:
                raise Refusal(f"{info.rapp} did not declare the service {req.action_name!r} in its manifest",
                              ErrorCode.PERMISSION)

    async def token_info(self, token: str) -> TokenInfo:
        if not token:
            raise Refusal("missing token: log in first and send the token with every call", ErrorCode.NO_TOKEN)
        if self.primary is not None:
            return await self._remote_token_info(token)
        info = self._tokens.get(token)
        if info is None:
            info = await asyncio.to_thread(self.directory.lookup, token)
            if info is None:
                raise Refusal("unknown token", ErrorCode.BAD_TOKEN)
            self._tokens[token] = info
        if time.time() > info.expires_at:
            self._tokens.pop(token, None)
            await asyncio.to_thread(self.directory.revoke, token)
            raise Refusal("token expired: log in again", ErrorCode.EXPIRED_TOKEN)
        return info

    async def revoke_token(self, token: str) -> bool:
        """Revoke a token here and, at once, on every live replica (each also forgets it by itself
        within TOKEN_CACHE_S). False if it was unknown."""
        self._tokens.pop(token, None)
        gone = await asyncio.to_thread(self.directory.revoke, token)
        note = D.TokenRevoked(digest=D.token_digest(token))
        await asyncio.gather(*(self.request(r.jid, note, timeout=2.0, retries=0) for r in self.platforms.live()),
                             return_exceptions=True)
        return gone

    async def _issue(self, user: str, ttl_s: float, **kw) -> tuple[str, float]:
        return await asyncio.to_thread(self.directory.issue, user, ttl_s, **kw)

    async def register_user(self, req: P.RegisterUser, ctx) -> Done:
        try:
            await asyncio.to_thread(self.directory.add_user, req.user, req.password)
        except DirectoryError as e:
            code = ErrorCode.DUPLICATE if e.code == ErrorCode.DUPLICATE else ErrorCode.INVALID
            raise Refusal(str(e) if code == ErrorCode.INVALID else f"user {req.user!r} already registered", code) from None
        return Done()

    async def login(self, req: P.Login, ctx) -> P.TokenReply:
        if not await asyncio.to_thread(self.directory.check_login, req.user, req.password):
            raise Refusal("unknown user or wrong password", ErrorCode.BAD_LOGIN)
        token, expires = await self._issue(req.user, req.ttl_s, holder=ctx.sender)
        return P.TokenReply(token=token, expires_at=expires, user=req.user)

    async def issue_app_token(self, req: P.IssueAppToken, ctx) -> P.TokenReply:
        unknown = sorted(set(req.services) - set(actions(P.ONTOLOGY)))
        if unknown:
            raise Refusal(f"{req.rapp} declares unknown services: {', '.join(unknown)}", ErrorCode.UNKNOWN_SERVICE)
        token, expires = await self._issue(ctx.user, req.ttl_s, holder=bare(req.holder_jid), rapp=req.rapp,
                                           services=frozenset(req.services), issuer=ctx.sender,
                                           not_after=ctx.token.expires_at)
        return P.TokenReply(token=token, expires_at=expires, user=ctx.user)

    async def verify_token(self, req: P.VerifyToken, ctx) -> P.TokenOwner:
        """For the Store (only): who holds a token a download request came with."""
        if ctx.sender != self.store:
            raise Refusal("only the Store verifies tokens", ErrorCode.FORBIDDEN)
        info = await self.token_info(req.token)
        return P.TokenOwner(user=info.user, holder=info.holder, rapp=info.rapp)

    async def register_robot(self, req: P.RegisterRobot, ctx) -> Done:
        if bare(req.core_jid) != ctx.sender:
            raise Refusal(f"{ctx.sender} cannot register a robot for {req.core_jid}", ErrorCode.FORBIDDEN)
        if is_rapp_account(ctx.sender):
            raise Refusal("a RApp run cannot register robots", ErrorCode.FORBIDDEN)
        known = self.robots.get(req.robot_id)
        if known is not None and bare(known.core_jid) != ctx.sender:
            raise Refusal(f"robot {req.robot_id!r} is registered by {bare(known.core_jid)}", ErrorCode.DUPLICATE)
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
        """A service as one step (s3: a Core's command interpreted): admitted, then executed."""
        memory = {"action": req.action_name, "request": req, "ctx": ctx}
        await self.admit_service(memory)
        return await self.execute_service(memory)

    async def admit_service(self, memory: dict) -> None:
        """s4's first step: past `max_pending` concurrent calls a new one is refused with a reason
        rather than left unanswered (ping and list_services, no service's work, always pass)."""
        if memory["action"] not in self.services:
            return
        if self.pending >= self.max_pending:
            raise Refusal(f"platform busy: {self.pending} calls in progress, retry shortly", ErrorCode.BUSY)
        self.pending += 1
        memory["admitted"] = True

    async def execute_service(self, memory: dict):
        """s4's second step: the service's work, in the pool's processes or a worker thread."""
        from agents.services.context import ServiceContext
        from agents.services.errors import ServiceError

        req, ctx = memory["request"], memory["ctx"]
        if not memory.get("admitted"):
            return await self._handlers[memory["action"]](req, ctx)
        spec = self.services[req.action_name]
        call = ServiceContext(user=ctx.user, state=self.state)
        try:
            if self.service_pool is not None and spec.pooled:
                return await self.service_pool.run(req.action_name, req, call)
            return await asyncio.to_thread(spec.run, req, call)
        except ServiceError as e:
            raise Failure(str(getattr(e, "reason", e)), getattr(e, "code", ErrorCode.SERVICE_ERROR)) from None
        finally:
            memory["admitted"] = False
            self.pending -= 1
            self.served += 1

    # -- several Platform agents (agents/platform_directory.py) ---------------------------------
    async def platform_report(self, req: D.PlatformReport, ctx) -> Done:
        """A replica's registration and heartbeat: accepted from the replicas this primary names."""
        if ctx.sender not in self.platforms.allowed:
            self.record_structure("refused", action="platform_report", by=ctx.sender)
            raise Refusal(f"{ctx.sender} is not a replica of {self.address}", ErrorCode.FORBIDDEN)
        if not self.platforms.report(ctx.sender, req):
            self.record_structure("replica-joined", replica=ctx.sender, capacity=req.capacity,
                                  services=sorted(set(req.services) & D.REPLICATED))
        return Done()

    async def list_platforms(self, req: D.ListPlatforms, ctx) -> D.PlatformList:
        info = await self.token_info(req.token)
        if info.holder != ctx.sender:
            raise Refusal(f"this token was issued to another agent, not to {ctx.sender}", ErrorCode.BAD_TOKEN)
        me = D.PlatformEntry(jid=self.address, services=sorted(self.services), capacity=self.capacity,
                             outstanding=self.pending, primary=True)
        return D.PlatformList(platforms=self.platforms.entries(me))

    async def lookup_token(self, req: D.LookupToken, ctx) -> D.TokenRecord:
        if ctx.sender not in self.platforms.allowed:
            raise Refusal(f"only this Platform's replicas look tokens up, not {ctx.sender}", ErrorCode.FORBIDDEN)
        info = await self.token_info(req.token)
        return D.TokenRecord(user=info.user, expires_at=info.expires_at, holder=info.holder, rapp=info.rapp,
                             services=None if info.services is None else sorted(info.services), issuer=info.issuer)

    # replica side
    async def primary_only(self, req, ctx):
        raise Refusal(f"{req.action_name} is served by the primary Platform {self.primary}, not by this replica",
                      ErrorCode.NOT_SERVING)

    async def _remote_token_info(self, token: str) -> TokenInfo:
        """The primary's answer about a token, trusted for TOKEN_CACHE_S (revocations are also pushed)."""
        digest = D.token_digest(token)
        hit = self._remote_tokens.get(digest)
        if hit is None or time.monotonic() - hit[1] > D.TOKEN_CACHE_S:
            try:
                rec = await self.request(self.primary, D.LookupToken(token=token), timeout=10.0)
            except RequestRefused as e:
                self._remote_tokens.pop(digest, None)
                raise Refusal(e.reason, e.code) from None
            except RequestError as e:
                raise Refusal(f"cannot verify the token now: the primary Platform did not answer ({e.reason})",
                              ErrorCode.UNAVAILABLE) from None
            info = TokenInfo(rec.user, rec.expires_at, rec.holder, rec.rapp,
                             None if rec.services is None else frozenset(rec.services), rec.issuer)
            hit = self._remote_tokens[digest] = (info, time.monotonic())
            if len(self._remote_tokens) > 10_000:  # old entries are useless after TOKEN_CACHE_S anyway
                now = time.monotonic()
                self._remote_tokens = {k: v for k, v in self._remote_tokens.items() if now - v[1] <= D.TOKEN_CACHE_S}
        info = hit[0]
        if time.time() > info.expires_at:
            raise Refusal("token expired: log in again", ErrorCode.EXPIRED_TOKEN)
        return info

    async def token_revoked(self, req: D.TokenRevoked, ctx) -> Done:
        if ctx.sender != self.primary:
            raise Refusal(f"only the primary Platform revokes tokens here, not {ctx.sender}", ErrorCode.FORBIDDEN)
        self._remote_tokens.pop(req.digest, None)
        return Done()

    async def _report_loop(self) -> None:
        """Register with the primary and report the load every REPORT_S (the primary forgets a
        replica it has not heard from for STALE_S)."""
        served = sorted(D.REPLICATED & set(self.services))
        told = False
        while True:
            try:
                await self.request(self.primary, D.PlatformReport(services=served, capacity=self.capacity,
                                                                  outstanding=self.pending, served=self.served),
                                   timeout=5.0, retries=0)
                if not told:
                    self.record_structure("replica-registered", primary=self.primary, services=served)
                    told = True
            except RequestError as e:
                if told or not getattr(self, "_report_warned", False):
                    log.warning("load report to %s failed: %s", self.primary, e)
                    self._report_warned, told = True, False
            await asyncio.sleep(D.REPORT_S)

    # -- Cloud Agents -----------------------------------------------------------------------------
    async def cloud_download(self, memory: dict) -> None:
        """A Cloud Agent for the Dynamic Agent that asks (s5 of fig. 6: download, build, start). Download: who may ask (its Dynamic Agent, once per run), then the package from the Store."""
        req, ctx = memory["request"], memory["ctx"]
        owner = ctx.sender  # a Cloud Agent serves the agent that asked for it, nobody named in content
        if req.owner_jid and bare(req.owner_jid) != owner:
            raise Refusal(f"{owner} cannot start a Cloud Agent for {req.owner_jid}", ErrorCode.FORBIDDEN)
        cores = {bare(r.core_jid) for r in self.robots.values()}
        if owner in self.clouds or ctx.token.services is None or ctx.token.issuer not in cores:
            # a Cloud Agent's own token was issued by its Dynamic Agent, a user's by nobody
            raise Refusal("only a Dynamic Agent (a token its Core asked for) starts a Cloud Agent", ErrorCode.FORBIDDEN)
        claim = self._cloud_runs.get(owner) or CloudClaim()
        if claim.started:
            raise Refusal(f"{owner} has started its Cloud Agent already: one per run", ErrorCode.FORBIDDEN)
        if claim.starting:
            raise Refusal(f"{owner}'s Cloud Agent is starting: one per run", ErrorCode.FORBIDDEN)
        if claim.attempts >= CLOUD_START_ATTEMPTS:
            raise Refusal(f"{owner}'s Cloud Agent failed to start {claim.attempts} times: no more tries this run",
                          ErrorCode.FORBIDDEN)
        claim.attempts, claim.starting = claim.attempts + 1, True
        self._cloud_runs[owner] = claim
        while len(self._cloud_runs) > 10_000:  # the oldest runs' entries go (their tokens are long dead)
            self._cloud_runs.pop(next(iter(self._cloud_runs)))
        memory["claim"] = claim
        try:
            info, data = await download_package(self, self.store, req.rapp, req.version)
        except RequestError as e:
            raise Failure(f"cannot fetch {req.rapp} from the Store: {e.reason}", ErrorCode.STORE) from None
        if not info.manifest.get("cloud_entry_point"):
            raise Refusal(f"{req.rapp} has no Cloud Agent part", ErrorCode.NO_CLOUD_PART)
        memory["owner"], memory["info"], memory["data"] = owner, info, data

    async def cloud_build(self, memory: dict) -> None:
        """s5, build: the package unpacked (checked again) into a run directory of its own."""
        from ontology.package import unpack_package

        info = memory["info"]
        n = next(self._serial)
        workdir = self.workdir / f"{n:04d}-{info.name}"
        await asyncio.to_thread(unpack_package, memory.pop("data"), workdir / "package")
        memory["workdir"] = workdir

    async def cloud_start(self, memory: dict) -> P.CloudAgentReply:
        """s5, start: its account and token, its process in the sandbox, until it says it serves.
        A start that fails leaves the run free to try again (CLOUD_START_ATTEMPTS in all)."""
        reply = await self._cloud_start(memory)
        memory["claim"].started = True  # its `starting` ends with the pass (_pass)
        return reply

    async def _cloud_start(self, memory: dict) -> P.CloudAgentReply:
        req, ctx, info, workdir, owner = (memory[k] for k in ("request", "ctx", "info", "workdir", "owner"))
        prefix = f"cloud-{info.name}".replace("_", "-")
        worker = self._cloud_worker()
        try:
            # a warm worker's account, or one reserved for a cold start: either registers itself at its
            # login (CloudAgent), so no XMPP session of the Platform's own runs in the middle of a start
            ident = worker.login if worker is not None else self.accounts.reserve(prefix)
            jid = self.settings.jid(ident.name)
            scope = ctx.token
            # the Cloud Agent is RApp code: never more than its manifest declares
            services = frozenset(info.manifest.get("services") or ()) & (scope.services or frozenset(
                info.manifest.get("services") or ()))
            token, _ = await self._issue(ctx.user, max(60.0, scope.expires_at - time.time()), holder=jid,
                                         rapp=info.name, services=services, issuer=ctx.sender,
                                         not_after=scope.expires_at)
            spec = SpawnSpec(kind="cloud", name=ident.name, password=ident.password, package_dir="",
                             owner=owner, platform=self.address, token=token)
            proc = self._spawn(spec, workdir)
            session = CloudSession(jid=jid, rapp=info.name, version=info.version, owner=owner, user=ctx.user,
                                   process=proc, account=ident, supervisor=scope.issuer, token=token)
            self.clouds[session.jid] = session
        except BaseException:
            if worker is not None:  # not handed its run: let go, its account removed
                await self.warm_pool.discard(worker)
            raise
        proc.on_refusal = lambda refusal, s=session: self._sandbox_refused(s, refusal)
        await proc.start(worker=worker)
        self.record_structure("cloud-spawn", cloud=session.jid, rapp=info.name, owner=owner, pid=proc.pid,
                              sandbox=proc.sandboxed, warm=getattr(proc, "warm", False))
        waiter = asyncio.create_task(session.ready.wait())
        exited = asyncio.create_task(proc.wait())
        done, _ = await asyncio.wait({waiter, exited}, timeout=self.settings.start_timeout + 10,
                                     return_when=asyncio.FIRST_COMPLETED)
        waiter.cancel()
        if not session.ready.is_set():
            exited.cancel()
            await self._kill_cloud(session, "did not start")
            raise Failure(f"Cloud Agent of {req.rapp} did not start: {proc.stderr_tail(500)}", ErrorCode.CLOUD_START)
        exited.cancel()
        session.restartable = bool(info.manifest.get("cloud_restartable"))
        session.watcher = asyncio.create_task(self._watch_cloud(session, spec, workdir))
        return P.CloudAgentReply(jid=session.jid, rapp=info.name, version=info.version)

    def start_cloud_workers(self) -> None:
        """Fill the Cloud Agents' warm pool now. Otherwise it starts at the first Cloud Agent, not at
        setup: most RApps have no Cloud part, and an idle worker costs ~160 MB and a second of CPU
        (the first Cloud Agent starts cold). A deployment that expects many robots to start Cloud
        Agents at once sizes the pool to them (`rapp agent platform --warm-workers N`)."""
        if self.cloud_mode == "process" and not self._pool_started:
            self._pool_started = True
            self.warm_pool.start()

    async def _worker_account(self):
        return self.accounts.reserve("cloud")  # registered by the worker at its login

    def _cloud_worker(self):
        """An idle warm worker, logged in under an account of its own (which the run takes), or None."""
        if self.cloud_mode != "process":
            return None
        self.start_cloud_workers()
        return self.warm_pool.take()

    def _spawn(self, spec: SpawnSpec, workdir: Path):
        # no pool: a warm worker comes only from _cloud_worker, with the account the spec names
        return spawn_agent(spec, workdir, self.settings, mode=self.cloud_mode, limits=self.limits,
                           sandbox=self.sandbox)

    async def _watch_cloud(self, session: CloudSession, spec: SpawnSpec, workdir: Path) -> None:
        """A Cloud Agent whose process ends unasked: its Dynamic Agent is told at once (the SDK
        raises CloudAgentLost); restarted once, same JID, where the manifest allows."""
        while True:
            code = await session.process.wait()
            if self.clouds.get(session.jid) is not session:
                return  # stopped on purpose
            restart = session.restartable and not session.restarted
            reason = f"Cloud Agent {session.jid} of {session.rapp} exited with code {code}"
            # the request it had taken last, out of its run directory before a restart reuses it
            kept = await asyncio.to_thread(
                keep_crash_input, Path(session.process.workdir) / BOX_NAME,
                self._crash_dir() / f"{session.jid.split('@')[0]}-{time.time():.0f}.json")
            self.record_structure("cloud-lost", cloud=session.jid, rapp=session.rapp, exit_code=code,
                                  restart=restart, stderr=await asyncio.to_thread(session.process.last_words),
                                  input=str(kept) if kept else None)
            if restart:  # told at once: a restart under load can outlast the calls in flight
                await self.notify(session.owner, P.CloudAgentDown(jid=session.jid, reason=reason, restarting=True),
                                  ontology=P.ONTOLOGY, action="cloud_agent_down")
                try:
                    restart = await self._restart_cloud(session, spec, workdir)
                except Exception as e:  # noqa: BLE001 - a failed restart is a lost Cloud Agent: still told
                    log.warning("restarting Cloud Agent %s failed: %s: %s", session.jid, type(e).__name__, e)
                    restart = False
            await self.notify(session.owner, P.CloudAgentDown(jid=session.jid, reason=reason, restarted=restart),
                              ontology=P.ONTOLOGY, action="cloud_agent_down")
            if not restart:
                await self._kill_cloud(session, "process exited")
                return

    def _crash_dir(self) -> Path:
        """Next to the trace that records the losses (a temporary work directory goes at stop)."""
        trace = self.settings.trace_file
        return (Path(trace).parent if trace else self.workdir) / "crashes"

    async def _restart_cloud(self, session: CloudSession, spec: SpawnSpec, workdir: Path) -> bool:
        """Start the Cloud Agent again under its JID; True once it serves (its Dynamic Agent, told
        it is restarting, failed the calls in flight and holds new ones until told it serves)."""
        session.restarted = True
        session.ready.clear()
        await session.process.end(grace=0.0)  # whatever of its uid left its group dies before the directory is reused
        session.process = self._spawn(spec, workdir)
        session.process.on_refusal = lambda refusal, s=session: self._sandbox_refused(s, refusal)
        await session.process.start()
        self.record_structure("cloud-spawn", cloud=session.jid, rapp=session.rapp, owner=session.owner,
                              pid=session.process.pid, sandbox=session.process.sandboxed, restart=True)
        try:
            await asyncio.wait_for(session.ready.wait(), self.settings.start_timeout + 10)
            return True
        except asyncio.TimeoutError:
            return False

    async def cloud_ready(self, req: P.CloudReady, ctx) -> Done:
        session = self.clouds.get(ctx.sender)
        if session is None:
            raise Refusal(f"{ctx.sender} is not a Cloud Agent of this Platform", ErrorCode.UNKNOWN_CLOUD)
        session.ready.set()
        if self.cloud_nice:
            session.process.yield_cpu(self.cloud_nice)
        return Done()

    def _may_stop(self, session: CloudSession, sender: str) -> bool:
        """Its Dynamic Agent, or the Core that supervises that Dynamic Agent (server identities)."""
        return sender in (session.owner, session.supervisor)

    async def stop_cloud(self, req: P.StopCloudAgent, ctx) -> Done:
        session = self.clouds.get(bare(req.jid))
        if session is None:
            raise Refusal(f"no Cloud Agent {req.jid}", ErrorCode.NOT_FOUND)
        if not self._may_stop(session, ctx.sender):
            self.record_structure("refused", action="stop_cloud_agent", by=ctx.sender, cloud=session.jid)
            raise Refusal(f"{ctx.sender} does not own {req.jid}", ErrorCode.FORBIDDEN)
        await self._kill_cloud(session, f"stopped by {ctx.sender}")
        return Done()

    async def release_clouds(self, req: P.ReleaseCloudAgents, ctx) -> P.Released:
        run = bare(req.owner_jid)
        for session in [c for c in self.clouds.values() if c.owner == run]:
            if not self._may_stop(session, ctx.sender):
                raise Refusal(f"{req.owner_jid}'s Cloud Agents are not {ctx.sender}'s to stop", ErrorCode.FORBIDDEN)
            await self._kill_cloud(session, f"owner {req.owner_jid} ended")
        if ctx.token.issuer is None and ctx.token.services is None:  # the Core (a login token): told what was refused
            return P.Released(refused=self._refused.pop(run, []))
        return P.Released()

    def _sandbox_refused(self, session: CloudSession, refusal: dict) -> None:
        """What a Cloud Agent's sandbox refused it: traced, and kept for its run's Core."""
        self.record_structure("refused", by="sandbox", sender=session.jid, action=refusal["what"],
                              reason=refusal.get("why", ""), count=refusal["count"], rapp_account=True)
        kept = self._refused.setdefault(session.owner, [])
        what = f"{refusal['what']} (its Cloud Agent)"
        same = next((r for r in kept if r.what == what), None)
        if same is not None:
            same.count = max(same.count, refusal["count"])
        elif len(kept) < 50:
            kept.append(P.Refused(by="sandbox", what=what, why=refusal.get("why", ""), count=refusal["count"]))

    def note_refusal(self, sender: str, action: str, refusal) -> None:
        """Traced; kept for the run's Core when the sender is a RApp run (its Cloud Agent's count as its
        Dynamic Agent's), which `release_cloud_agents` answers with."""
        trace_refusal(self, sender, action, refusal)
        if not is_rapp_account(sender):
            return
        cloud = self.clouds.get(sender)
        run = cloud.owner if cloud is not None else sender
        kept = self._refused.setdefault(run, [])
        what = f"{action} by {sender.split('@')[0]}" if cloud is not None else action
        same = next((r for r in kept if r.what == what and r.why == refusal.reason[:200]), None)
        if same is not None:
            same.count += 1
        elif len(kept) < 50:
            kept.append(P.Refused(by=self.address, what=what, why=refusal.reason[:200]))
        while len(self._refused) > 1000:
            self._refused.pop(next(iter(self._refused)))

    async def _kill_cloud(self, session: CloudSession, reason: str) -> None:
        if self.clouds.pop(session.jid, None) is None:
            return
        if session.watcher is not None and session.watcher is not asyncio.current_task():
            session.watcher.cancel()
        # its token dies while it logs out and is killed (both before the answer, neither waiting
        # for the other); its exit code is None while the kernel still tears the process down
        code, _ = await asyncio.gather(session.process.end(grace=1.0), self.revoke_token(session.token))
        self.record_structure("cloud-destroy", cloud=session.jid, rapp=session.rapp, reason=reason,
                              exit_code=code)
        # it can no longer act and its token is dead: its reaping, account (a login of its own) and
        # run directory go after the reply (a fleet's 20 stops at once waited ~250 ms for them)
        cleanup = asyncio.create_task(self._clean_up_after(session))
        self._cleanups.add(cleanup)
        cleanup.add_done_callback(self._cleanups.discard)

    async def _clean_up_after(self, session: CloudSession) -> None:
        code = await session.process.wait()
        gone = await self.accounts.delete(session.account.name, session.account.password)
        self.record_structure("account-deleted" if gone else "account-kept", account=session.jid, exit_code=code)
        await asyncio.to_thread(shutil.rmtree, session.process.workdir, ignore_errors=True)
