"""Store Agent: the RAPP Store over XMPP, on a persistent StoreRepository (SQLite + blobs).

Packages travel in base64 chunks (ontology/chunks.py): `download_info` then `download_chunk` per
index; publishing sends `upload_chunk`s then `publish`. Repository calls run in a worker thread.
"""
from __future__ import annotations

import asyncio
import time
import uuid
from pathlib import Path

from ontology import store as S
from ontology.acl import Performative
from ontology.platform import VerifyToken
from ontology.registry import Done
from ontology.chunks import ChunkError, Reassembler, split_chunks
from ontology.errors import ErrorCode

from .base import RappAgent
from .errors import Failure, Refusal, RequestError
from .identity import is_rapp_account, trace_refusal
from .responder import Responder
from .store_repository import StoreError, StoreRepository

UPLOAD_TTL_S = 300.0
MAX_SUBSCRIBERS = 1000
MAX_UPLOADS = 32


def _summary(p) -> S.PackageSummary:
    return S.PackageSummary(**{k: getattr(p, k) for k in S.PackageSummary.model_fields})


def _details(info) -> S.PackageDetails:
    return S.PackageDetails(summary=_summary(info), owner=info.owner, manifest=info.manifest,
                            signer_key_id=info.signer_key_id, versions=info.versions)


class StoreAgent(RappAgent):
    def __init__(self, name: str = "store", data_dir: str | Path = "store-data", settings=None,
                 require_signature: bool = False, platform: str = "platform"):
        super().__init__(name, settings)
        self.platform = self.settings.jid(platform)  # verifies download tokens; downloads freely
        self._verified: dict[tuple[str, str], float] = {}  # (token, sender) -> when verified
        self.subscribers: dict[str, str | None] = {}  # JID -> robot type it asked about
        self.repo = StoreRepository(data_dir, require_signature=require_signature)
        self._uploads: dict[str, tuple[float, Reassembler]] = {}
        self._downloads: dict[tuple[str, str], tuple[float, list]] = {}

    async def setup(self) -> None:
        handlers = {
            "register_owner": self.register_owner, "register_robot": self.register_robot,
            "list_packages": self.list_packages, "search": self.search, "info": self.info,
            "versions": self.versions, "download_info": self.download_info,
            "download_chunk": self.download_chunk, "upload_chunk": self.upload_chunk,
            "publish": self.publish, "delete": self.delete,
        }
        responder = Responder(S.ONTOLOGY, {k: _store_errors(v) for k, v in handlers.items()})
        self.activate("store-service", responder, responder.make_template())
        subscriptions = Responder(S.ONTOLOGY, {"subscribe_catalogue": self.subscribe},
                                  performative=Performative.SUBSCRIBE)
        self.activate("store-subscriptions", subscriptions, subscriptions.make_template())

    # -- subscriptions (FIPA subscribe): Cores learn of new and removed RApps at once -------
    async def subscribe(self, req: S.SubscribeCatalogue, ctx) -> Done:
        self.subscribers.pop(ctx.sender, None)
        self.subscribers[ctx.sender] = req.robot_type
        while len(self.subscribers) > MAX_SUBSCRIBERS:  # the oldest go first
            self.subscribers.pop(next(iter(self.subscribers)))
        return Done()

    async def _tell_subscribers(self, event: str, name: str, versions: list[str], robot_types: list[str]) -> None:
        note = S.CatalogueChanged(event=event, name=name, versions=versions)
        for jid, robot_type in list(self.subscribers.items()):
            if robot_type is None or not robot_types or robot_type in robot_types:  # removals: all
                await self.notify(jid, note, ontology=S.ONTOLOGY, action="catalogue_changed")

    async def stop(self) -> None:
        await super().stop()
        self.repo.close()

    async def _repo(self, fn, *args, **kw):
        return await asyncio.to_thread(fn, *args, **kw)

    def note_refusal(self, sender: str, action: str, refusal) -> None:
        trace_refusal(self, sender, action, refusal)

    # -- owners and robots --------------------------------------------------------------------
    async def register_owner(self, req: S.RegisterOwner, ctx) -> Done:
        if is_rapp_account(ctx.sender):
            raise Refusal("a RApp run cannot register Store owners", ErrorCode.FORBIDDEN)
        try:
            await self._repo(self.repo.register_owner, req.owner, password=req.password,
                             public_key=req.public_key)
        except StoreError as e:
            if e.code != ErrorCode.DUPLICATE or not await self._repo(self.repo.verify_owner, req.owner, req.password):
                raise
        return Done()

    async def register_robot(self, req: S.RegisterRobot, ctx) -> Done:
        """Only the owner's own agent registers a robot: a sender holding the owner's Platform login
        token (a Core logged in as its owner; never a RApp, whose token is a RApp's)."""
        if is_rapp_account(ctx.sender):
            raise Refusal("a RApp run cannot register robots", ErrorCode.FORBIDDEN)
        if not req.token:
            raise Refusal("registering a robot needs the owner's Platform login token", ErrorCode.NO_TOKEN)
        try:
            holder = await self.request(self.platform, VerifyToken(token=req.token), timeout=10.0)
        except RequestError as e:
            raise Refusal(f"robot registration refused: {e.reason}", ErrorCode.BAD_TOKEN) from None
        if holder.holder != ctx.sender or holder.rapp is not None or holder.user != req.owner:
            raise Refusal(f"{ctx.sender} is not logged in to the Platform as {req.owner}", ErrorCode.FORBIDDEN)
        await self._repo(self.repo.register_robot, req.robot_id, req.robot_type, req.owner)
        self.record_structure("register", robot=req.robot_id, robot_type=req.robot_type,
                              by=ctx.sender, at="store")
        return Done()

    # -- catalogue ----------------------------------------------------------------------------
    async def list_packages(self, req: S.ListPackages, ctx) -> S.PackageList:
        rows = await self._repo(self.repo.list, req.robot_type)
        return S.PackageList(packages=[_summary(p) for p in rows])

    async def search(self, req: S.Search, ctx) -> S.PackageList:
        rows = await self._repo(self.repo.search, req.keyword, req.robot_type)
        return S.PackageList(packages=[_summary(p) for p in rows])

    async def info(self, req: S.Info, ctx) -> S.PackageDetails:
        return _details(await self._repo(self.repo.info, req.name, req.version))

    async def versions(self, req: S.GetVersions, ctx) -> S.Versions:
        return S.Versions(name=req.name, versions=await self._repo(self.repo.versions, req.name))

    # -- download -----------------------------------------------------------------------------
    async def _authorize_download(self, token: str, sender: str) -> None:
        """Downloads need a Platform token held by the sender (as in the original Store); the
        Platform itself is known by its server-authenticated JID."""
        if sender == self.platform:
            return
        if not token:
            raise Refusal("downloads need a Platform token: log in to the Platform first", ErrorCode.NO_TOKEN)
        now = time.monotonic()
        if now - self._verified.get((token, sender), -1e9) < UPLOAD_TTL_S:
            return
        try:
            owner = await self.request(self.platform, VerifyToken(token=token), timeout=10.0)
        except RequestError as e:
            raise Refusal(f"download refused: {e.reason}", ErrorCode.BAD_TOKEN) from None
        if owner.holder != sender:
            raise Refusal(f"download refused: the token was issued to another agent, not {sender}", ErrorCode.BAD_TOKEN)
        self._verified[(token, sender)] = now

    async def download_info(self, req: S.DownloadBegin, ctx) -> S.DownloadInfo:
        await self._authorize_download(req.token, ctx.sender)
        dl = await self._repo(self.repo.download, req.name, req.version)
        chunks = split_chunks(dl.data)
        self._downloads[(dl.manifest.name, dl.manifest.version)] = (time.monotonic(), chunks)
        self._expire()
        self.record_structure("download", rapp=dl.manifest.name, version=dl.manifest.version,
                              by=ctx.sender, size=len(dl.data), sha256=dl.sha256)
        return S.DownloadInfo(name=dl.manifest.name, version=dl.manifest.version, sha256=dl.sha256,
                              size=len(dl.data), chunks=len(chunks),
                              manifest=dl.manifest.model_dump(mode="json"))

    async def download_chunk(self, req: S.DownloadChunk, ctx) -> S.ChunkData:
        await self._authorize_download(req.token, ctx.sender)
        key = (req.name, req.version)
        if key not in self._downloads:
            dl = await self._repo(self.repo.download, req.name, req.version)
            self._downloads[key] = (time.monotonic(), split_chunks(dl.data))
        _, chunks = self._downloads[key]
        if req.index >= len(chunks):
            raise Refusal(f"chunk {req.index} out of range (package has {len(chunks)})", ErrorCode.OUT_OF_RANGE)
        return S.ChunkData(**chunks[req.index].model_dump())

    # -- publish ------------------------------------------------------------------------------
    async def upload_chunk(self, req: S.UploadChunk, ctx) -> S.UploadTicket:
        self._expire()
        upload_id = req.upload_id or uuid.uuid4().hex
        try:
            if upload_id not in self._uploads:
                if len(self._uploads) >= MAX_UPLOADS:
                    raise Refusal("too many uploads in progress; try again later", ErrorCode.BUSY)
                self._uploads[upload_id] = (time.monotonic(),
                                            Reassembler(total=req.chunk.total, sha256=req.chunk.sha256,
                                                        size=req.chunk.size,
                                                        max_size=self.repo.max_package_size))
            self._uploads[upload_id][1].add(req.chunk.model_dump())
        except ChunkError as e:
            self._uploads.pop(upload_id, None)
            raise Refusal(f"upload refused: {e}", ErrorCode.BAD_CHUNK) from None
        return S.UploadTicket(upload_id=upload_id)

    async def _check_owner(self, owner: str, password: str, sender: str) -> None:
        """Owner operations are decided on the server-authenticated sender: the account bound to
        the owner at its first publish; the owner's password is checked as well."""
        if not await self._repo(self.repo.verify_owner, owner, password):
            raise Refusal(f"owner {owner!r} unknown or wrong password", ErrorCode.FORBIDDEN)
        bound = await self._repo(self.repo.bind_owner, owner, sender)
        if bound != sender:
            self.record_structure("refused", action="owner-operation", owner=owner, by=sender)
            raise Refusal(f"owner {owner!r} publishes from {bound}, not from {sender}", ErrorCode.FORBIDDEN)

    async def publish(self, req: S.Publish, ctx) -> S.PackageDetails:
        await self._check_owner(req.owner, req.password, ctx.sender)
        entry = self._uploads.pop(req.upload_id, None)
        if entry is None:
            raise Refusal(f"no upload {req.upload_id!r} in progress", ErrorCode.NOT_FOUND)
        try:
            data = entry[1].result()
        except ChunkError as e:
            raise Refusal(f"upload incomplete or corrupt: {e}", ErrorCode.BAD_CHUNK) from None
        info = await self._repo(self.repo.publish, req.owner, data)
        self.record_structure("publish", rapp=info.name, version=info.version, by=req.owner)
        await self._tell_subscribers("published", info.name, [info.version], list(info.robot_types))
        return _details(info)

    async def delete(self, req: S.Delete, ctx) -> S.Deleted:
        await self._check_owner(req.owner, req.password, ctx.sender)
        gone = await self._repo(self.repo.delete, req.name, req.version, owner=req.owner)
        for v in gone:
            self._downloads.pop((req.name, v), None)
        await self._tell_subscribers("removed", req.name, gone, [])
        return S.Deleted(name=req.name, versions=gone)

    def _expire(self) -> None:
        now = time.monotonic()
        for table in (self._uploads, self._downloads):
            for key in [k for k, (t, _) in table.items() if now - t > UPLOAD_TTL_S]:
                table.pop(key, None)
        for key in [k for k, t in self._verified.items() if now - t > UPLOAD_TTL_S]:
            self._verified.pop(key, None)


def _store_errors(handler):
    """StoreError -> refuse (forbidden, not found, duplicate) or failure (corrupt), with reason."""

    async def wrapped(req, ctx):
        try:
            return await handler(req, ctx)
        except StoreError as e:
            if e.code == ErrorCode.CORRUPT:
                raise Failure(str(e), e.code) from None
            raise Refusal(str(e), e.code) from None

    return wrapped
