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
from .runtime import load_entry_point


class CloudAgent(RappAgent):
    def __init__(self, name: str, *, manifest: Manifest, package_dir: str | Path, owner: str,
                 token: str = "", settings=None, password: str | None = None):
        super().__init__(name, settings, password)
        self.manifest, self.package_dir = manifest, Path(package_dir)
        self.owner, self.token = owner, token
        self.service = None
        self._stopped = asyncio.Event()

    async def setup(self) -> None:
        cls = load_entry_point(self.package_dir, self.manifest.cloud_entry_point)
        self.service = cls(self)
        responder = Responder(self.service.ontology, self.service.handlers(), check=self._only_owner)
        self.activate("cloud-service", responder, responder.make_template())

    def _only_owner(self, req, ctx) -> None:
        if self.owner and ctx.sender != self.owner:
            raise Refusal(f"this Cloud Agent serves {self.owner} only", ErrorCode.FORBIDDEN)

    async def run_to_end(self, platform: str) -> int:
        from ontology.platform import CloudReady

        await self.start()
        await self.request(platform, CloudReady(jid=self.address), timeout=10.0)
        await self._stopped.wait()
        await self.stop()
        return 0
