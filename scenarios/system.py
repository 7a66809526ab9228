"""Bring up a RAPP system in one call: XMPP server, Store, Platform, robots with Core Agents,
and their users as plain XMPP chat clients. Used by scenarios, tests and benchmarks.

    async with RappSystem(workdir) as system:
        await system.publish("rapps/hazard_detection")
        robot = await system.add_robot("nao", world=world)
        await robot.user.say(robot.core.address, "check the hazards")
"""
from __future__ import annotations

import asyncio
import contextlib
import tempfile
from dataclasses import dataclass
from pathlib import Path

from agents.base import RappAgent
from agents.core_agent import CoreAgent, CoreOptions
from agents.platform_agent import PlatformAgent
from agents.process import Limits
from agents.runtime import WARM_EXTRA_IMPORTS
from agents.store_agent import StoreAgent
from agents.store_client import publish_package
from ontology.package import build_package_bytes, generate_keypair
from xmpp_server import EmbeddedServer, XmppSettings
from xmpp_server.credentials import generate_password
from xmpp_server.link import FaultyLink, LinkFaults

from .owner import OwnerClient

# what warm workers import ahead besides the runtime: the SDK every RApp imports (~9 ms of a hand-off)
# with its pose filter (numpy: 85 ms and 134 ms of CPU at a hazard-detection hand-off, 20 of them
# in a fleet's burst), and for Cloud parts its vision helpers too (~7 ms more) beside numpy, cv2, scipy
DYNAMIC_WARM_IMPORTS = ("rapps.sdk", "rapps.sdk.ekf")
CLOUD_WARM_IMPORTS = (*WARM_EXTRA_IMPORTS, "rapps.sdk", "rapps.sdk.vision")

DEVELOPER = ("developer", "developer-secret")


async def wait_until(pred, timeout: float = 30.0, what: str = "condition", interval: float = 0.02) -> None:
    """Poll `pred()` every `interval` seconds until it is true; TimeoutError after `timeout` seconds."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not pred():
        if loop.time() > deadline:
            raise TimeoutError(f"{what} not reached within {timeout:g}s")
        await asyncio.sleep(interval)


@dataclass
class RobotHandle:
    robot_id: str
    robot_type: str
    core: CoreAgent
    user: OwnerClient  # a plain chat client that also takes the Core's task records
    api: object


class RappSystem:
    def __init__(self, workdir: str | Path | None = None, *, settings: XmppSettings | None = None,
                 trace_file: str | Path | None = None, force_xmpp: bool | None = None,
                 limits: Limits = Limits(), services: dict | None = None,
                 platform_kw: dict | None = None, store_and_platform: bool = True, store_kw: dict | None = None):
        # store_and_platform=False: they run elsewhere (own processes, `rapp agent store/platform`)
        # under the names "store" and "platform"; publish() and the Cores reach them over XMPP
        self._own_agents = store_and_platform
        self._services = services
        self._platform_kw = platform_kw or {}
        # a run's Store builds nothing unless asked (`store_kw={"build": True}`): a scenario runs a
        # RApp, and a RApp's own test that runs one (scenarios.run_rapp) would wait on its build
        self._store_kw = {"build": False, **(store_kw or {})}
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="rapp-run-"))
        self.workdir.mkdir(parents=True, exist_ok=True)
        self._given_settings = settings
        self._trace_file = trace_file
        self._force_xmpp = force_xmpp
        self.limits = limits
        self.server: EmbeddedServer | None = None
        self.settings: XmppSettings | None = None
        self.store: StoreAgent | None = None
        self.platform: PlatformAgent | None = None
        self.publisher: RappAgent | None = None
        self.robots: list[RobotHandle] = []
        self.links: dict[str, FaultyLink] = {}  # robot id -> its flaky link (add_robot's `link`)
        self._on_stop: list = []  # callbacks run first at stop (e.g. ending a progress display)
        # this run's package signer: what publish() builds is signed, what its Cores run must be
        self.signing_key, self.public_key = generate_keypair()

    async def start(self) -> "RappSystem":
        overrides = {"trace_file": self._trace_file, "force_xmpp": self._force_xmpp}
        given = self._given_settings
        if given is None or (given.credentials_dir is None and not given.password):
            # every agent of this run has its own password, in a directory of this run
            overrides["credentials_dir"] = self.workdir / "credentials"
        if self._given_settings is None:
            self.server = EmbeddedServer(db=self.workdir / "xmpp.db", trace_file=self._trace_file)
            await self.server.astart()
            self.settings = self.server.settings(**overrides)
        else:
            self.settings = self._given_settings.model_copy(
                update={k: v for k, v in overrides.items() if v is not None})
        self.publisher = RappAgent("publisher", self.settings)
        if not self._own_agents:
            await self.publisher.start()
            return self
        self.store = StoreAgent("store", self.workdir / "store", self.settings, **self._store_kw)
        # cloud_nice 0: this Platform shares its process with the simulated robots, which stand for
        # the robots' own CPUs; a Cloud Agent below it would yield to the simulation too, which a real
        # robot's CPU never asks of it. A Platform of its own (`rapp agent platform`) keeps
        # agents/platform_agent.py CLOUD_NICE.
        self.platform = PlatformAgent("platform", store="store", settings=self.settings, services=self._services,
                                      workdir=self.workdir / "platform", limits=self.limits,
                                      **{"warm_imports": CLOUD_WARM_IMPORTS, "cloud_nice": 0, **self._platform_kw})
        await asyncio.gather(self.store.start(), self.platform.start(), self.publisher.start())
        return self

    @property
    def store_address(self) -> str:
        return self.settings.jid("store")

    @property
    def platform_address(self) -> str:
        return self.settings.jid("platform")

    async def publish(self, src_dir: str | Path, owner: tuple[str, str] = DEVELOPER) -> str:
        """Build the RApp in src_dir, signed with this run's key, and publish it through the Store
        Agent (over XMPP)."""
        from ontology.store import RegisterOwner

        await self.publisher.request(self.store_address, RegisterOwner(owner=owner[0], password=owner[1]))
        data = await asyncio.to_thread(build_package_bytes, src_dir, self.signing_key)
        details = await publish_package(self.publisher, self.store_address, owner[0], owner[1], data)
        return f"{details.summary.name} {details.summary.version}"

    async def add_robot(self, robot_type: str, *, api, robot_id: str | None = None,
                        user: str | None = None, link: LinkFaults | None = None, **core_kw) -> RobotHandle:
        """`link`: the robot's connection to the server is a flaky one (xmpp_server/link.py): its Core
        and the Dynamic Agents it starts connect through it; the owner's chat client does not."""
        n = len(self.robots) + 1
        robot_id = robot_id or f"{robot_type}{n}"
        user_name = user or f"owner-{robot_id}"
        chat = OwnerClient(user_name, self.settings)
        await chat.start()
        core_kw.setdefault("trusted_keys", [self.public_key])
        core_kw.setdefault("require_signature", True)
        core_kw.setdefault("warm_imports", DYNAMIC_WARM_IMPORTS)
        settings = self.settings
        if link is not None:
            if not settings.force_xmpp:  # agents of one process would talk past the server and the link
                raise ValueError("a robot's flaky link needs the system's force_xmpp=True")
            relay = await FaultyLink(settings.addresses()[0], link).start()
            self.links[robot_id] = relay
            settings = settings.model_copy(update={"host": relay.address[0], "port": relay.port, "fallback": []})
        options = CoreOptions(**{"workdir": self.workdir / f"core-{robot_id}", "limits": self.limits, **core_kw})
        core = CoreAgent(f"core-{robot_id}", robot_id=robot_id, robot_type=robot_type, robot_api=api,
                         owner=user_name, platform="platform", store="store", user=user_name,
                         password=generate_password(), settings=settings, options=options)
        await core.start()
        handle = RobotHandle(robot_id, robot_type, core, chat, api)
        self.robots.append(handle)
        return handle

    def on_stop(self, callback) -> None:
        self._on_stop.append(callback)

    async def stop(self) -> None:
        for callback in self._on_stop:
            callback()
        for r in self.robots:
            with contextlib.suppress(Exception):
                if r.core.dynamic is not None and r.core.dynamic.process is not None:
                    await r.core.dynamic.process.stop(grace=0.5)
                await r.core.stop()
            with contextlib.suppress(Exception):
                await r.user.stop()
        for relay in self.links.values():
            await relay.stop()
        for agent in (self.publisher, self.platform, self.store):
            if agent is not None:
                with contextlib.suppress(Exception):
                    await agent.stop()
        if self.server is not None:
            await asyncio.to_thread(self.server.close)

    async def __aenter__(self):
        return await self.start()

    async def __aexit__(self, *exc):
        await self.stop()
