"""Cloud Agent: a RApp's platform-side part, built from Store bytes, serving its Dynamic Agent
only (paper 000 sec. 5.4). It lives until the Platform stops it."""
from __future__ import annotations

import asyncio
from pathlib import Path

from ontology.manifest import Manifest
from ontology.errors import ErrorCode

from .base import RappAgent
from .errors import Refusal
from .responder import Responder
from .entry_point import load_entry_point



class CloudAgent(RappAgent):
    """Built with its run (`manifest`, `package_dir`, `owner`), or without one by a warm Cloud worker
    that logs in while idle (agents/runtime.py); `begin()` then gives it its run."""

    def __init__(self, name: str, *, manifest: Manifest | None = None, package_dir: str | Path | None = None,
                 owner: str = "", token: str = "", settings=None, password: str | None = None):
        super().__init__(name, settings, password)
        self.manifest, self.package_dir = manifest, Path(package_dir) if package_dir else None
        self.owner, self.token = owner, token
        self.service = None
        self.crash_box = None  # agents/crash_box.py CrashBox: in a process of its own (the runtime sets it)
        self._stopped = asyncio.Event()

    async def setup(self) -> None:
        if self.manifest is not None:
            self._serve()

    def begin(self, manifest: Manifest, package_dir: str | Path, owner: str, token: str = "") -> None:
        """The run of a Cloud Agent already logged in: its RApp code imported and serving now."""
        if self.service is not None:
            raise RuntimeError(f"{self.address} already serves {self.manifest.name}")
        self.manifest, self.package_dir, self.owner, self.token = manifest, Path(package_dir), owner, token
        self._serve()

    def _serve(self) -> None:
        cls = load_entry_point(self.package_dir, self.manifest.cloud_entry_point)
        self.service = cls(self)
        # every ontology the part serves (its own, the SDK's localization it extends), a responder each
        served = (self.service.served() if hasattr(self.service, "served")
                  else {self.service.ontology: self.service.handlers()})
        for i, (ontology, handlers) in enumerate(served.items()):
            responder = Responder(ontology, {a: self._boxed(h) for a, h in handlers.items()}, check=self._taken)
            self.activate("cloud-service" if i == 0 else f"cloud-service-{ontology}", responder,
                          responder.make_template())

    def _taken(self, req, ctx) -> None:
        """Its owner's requests only."""
        if self.owner and ctx.sender != self.owner:
            raise Refusal(f"this Cloud Agent serves {self.owner} only", ErrorCode.FORBIDDEN)

    def _boxed(self, handler):
        """`handler`, with its request in the crash box (if any) while it is worked on."""
        async def run(req, ctx):
            if self.crash_box is None:
                return await handler(req, ctx)
            ticket = self.crash_box.hold(ctx.info.action, ctx.message.body or "")
            try:
                return await handler(req, ctx)
            finally:
                self.crash_box.release(ticket)
        return run

    async def run_to_end(self, platform: str) -> int:
        from ontology.platform import CloudReady

        if not self.is_alive():
            await self.start(auto_register=True)  # its account is only reserved (agents/identity.py reserve)
        await self.request(platform, CloudReady(jid=self.address), timeout=10.0)
        await self._stopped.wait()
        await self.stop()
        return 0
