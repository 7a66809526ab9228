"""Store Agent: the RAPP Store over XMPP, on a persistent StoreRepository (SQLite + blobs).

Packages travel in base64 chunks (ontology/chunks.py): `download_info` then `download_chunk` per
index; publishing sends `upload_chunk`s then `publish`. Repository calls run in a worker thread.

Per-robot builds (paper 000 sec. 6.2; agents/store_build.py): a publish is answered at once, its
builds queued, one per robot type the manifest declares; a builder task runs them one at a time,
each the package's own tests in a sandbox of its own, in a process of its own (the event loop never
waits on one). A version is listed for a type when its build for the type passed; a type whose
build failed is refused with the reason, and every build's log is kept (`builds`, `build_log`).
A package without tests is compiled only and listed "untested" (`require_tests=True`: refused).
The Cores subscribed are told of a version when a type of theirs is listed. Builds queued or
running when the Store stopped run at its next start. `build=False` (a scenario's Store, or one
inside a build) builds nothing: every declared type is listed "untested".
"""
from __future__ import annotations

import asyncio
import itertools
import logging
import os
import shutil
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

log = logging.getLogger("rapp.store")
UPLOAD_TTL_S = 300.0
MAX_SUBSCRIBERS = 1000
MAX_UPLOADS = 32


def _summary(p) -> S.PackageSummary:
    return S.PackageSummary(**{k: getattr(p, k) for k in S.PackageSummary.model_fields})


def _build(b) -> S.BuildInfo:
    return S.BuildInfo(**b.model_dump())


def _details(info) -> S.PackageDetails:
    return S.PackageDetails(summary=_summary(info), owner=info.owner, manifest=info.manifest,
                            signer_key_id=info.signer_key_id, versions=info.versions)


class StoreAgent(RappAgent):
    def __init__(self, name: str = "store", data_dir: str | Path = "store-data", settings=None,
                 require_signature: bool = False, platform: str = "platform", build: bool = True,
                 require_tests: bool = False, sandbox=None, build_timeout_s: float | None = None):
        super().__init__(name, settings)
        # never inside a build: a RApp's test that runs a whole system (scenarios.run_rapp) would build again
        self.build = build and os.environ.get("RAPP_STORE_BUILD") != "1"
        self.require_tests = require_tests
        self._sandbox = sandbox  # None: the machine's best (made at the first build)
        self.build_timeout_s = build_timeout_s
        self._builds: asyncio.Queue[tuple[str, str, str]] = asyncio.Queue()
        self._builder: asyncio.Task | None = None
        self._build_serial = itertools.count(1)
        self.platform = self.settings.jid(platform)  # verifies download tokens; downloads freely
        self._verified: dict[tuple[str, str], float] = {}  # (token, sender) -> when verified
        self.subscribers: dict[str, str | None] = {}  # JID -> robot type it asked about
        self.repo = StoreRepository(data_dir, require_signature=require_signature)
        self.build_dir = Path(data_dir) / "builds"  # each build's run directory, removed at its end
        self._uploads: dict[str, tuple[float, Reassembler]] = {}
        self._downloads: dict[tuple[str, str], tuple[float, list]] = {}

    async def setup(self) -> None:
        handlers = {
            "register_owner": self.register_owner, "register_robot": self.register_robot,
            "list_packages": self.list_packages, "search": self.search, "info": self.info,
            "versions": self.versions, "download_info": self.download_info,
            "download_chunk": self.download_chunk, "upload_chunk": self.upload_chunk,
            "publish": self.publish, "delete": self.delete, "builds": self.builds, "build_log": self.build_log,
        }
        responder = Responder(S.ONTOLOGY, {k: _store_errors(v) for k, v in handlers.items()})
        self.activate("store-service", responder, responder.make_template())
        subscriptions = Responder(S.ONTOLOGY, {"subscribe_catalogue": self.subscribe},
                                  performative=Performative.SUBSCRIBE)
        self.activate("store-subscriptions", subscriptions, subscriptions.make_template())
        await asyncio.to_thread(shutil.rmtree, self.build_dir, True)  # a stopped build's leftovers
        for b in await self._repo(self.repo.unfinished_builds):  # what a stopped Store had not built
            self._builds.put_nowait((b.name, b.version, b.robot_type))
        self._builder = asyncio.create_task(self._build_loop(), name="store-builder")

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
        if self._builder is not None:
            self._builder.cancel()  # its process group and control group killed (store_build.run_tests)
            await asyncio.gather(self._builder, return_exceptions=True)
        await super().stop()
        self.repo.close()
        await asyncio.to_thread(shutil.rmtree, self.build_dir, True)

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
        return await self._details(await self._repo(self.repo.info, req.name, req.version))

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
        builds = await asyncio.to_thread(self._first_builds, data)
        info = await self._repo(self.repo.publish, req.owner, data, builds)
        queued = [t for t, (state, _) in builds.items() if state == S.BuildState.QUEUED]
        self.record_structure("publish", rapp=info.name, version=info.version, by=req.owner,
                              builds={t: state for t, (state, _) in builds.items()})
        for robot_type in queued:
            self._builds.put_nowait((info.name, info.version, robot_type))
        if info.robot_types:  # listed at once (nothing to run): the Cores of those types are told now
            await self._tell_subscribers("published", info.name, [info.version], list(info.robot_types))
        return await self._details(info)

    async def _details(self, info) -> S.PackageDetails:
        details = _details(info)
        details.builds = [_build(b) for b in await self._repo(self.repo.builds, info.name, info.version)]
        return details

    def _first_builds(self, data: bytes) -> dict[str, tuple[str, str]]:
        """Each declared type's build as the publish leaves it: queued (its tests run next), failed
        (its sources do not compile), or untested (no tests, or this Store builds nothing)."""
        from ontology.package import PackageError, read_package, unpack_package

        from .store_build import compile_sources, has_tests

        try:
            pkg = read_package(data, max_size=self.repo.max_package_size, require_signature=self.repo.require_signature)
        except (PackageError, TypeError):
            return {}  # refused by the repository's own check, with its reason
        types = pkg.manifest.robot_types
        if not self.build:
            return {t: (S.BuildState.UNTESTED, "this Store builds nothing (build=False)") for t in types}
        scratch = self.build_dir / f"check-{uuid.uuid4().hex[:8]}"
        try:
            unpack_package(data, scratch / "package")
            errors = compile_sources(scratch / "package")
            tests = has_tests(scratch / "package")
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
        if errors:
            why = f"does not compile: {errors[0]}" + (f" (and {len(errors) - 1} more)" if len(errors) > 1 else "")
            return {t: (S.BuildState.FAILED, why) for t in types}
        if not tests:
            if self.require_tests:
                raise Refusal(f"{pkg.manifest.name} has no tests (tests/test_*.py): this Store builds and lists a "
                              "package per robot type by its own tests", ErrorCode.INVALID_PACKAGE)
            return {t: (S.BuildState.UNTESTED, "no tests (tests/test_*.py): compiled only") for t in types}
        return {t: (S.BuildState.QUEUED, "") for t in types}

    # -- builds (agents/store_build.py) ----------------------------------------------------------
    async def _build_loop(self) -> None:
        while True:
            name, version, robot_type = await self._builds.get()
            try:
                await self._build_one(name, version, robot_type)
            except asyncio.CancelledError:
                raise
            except Exception as e:  # noqa: BLE001 - one build's trouble never stops the others
                log.exception("build of %s %s for %s failed", name, version, robot_type)
                await self._repo(self.repo.set_build, name, version, robot_type, S.BuildState.FAILED,
                                 f"the Store could not build it: {type(e).__name__}: {e}", ended=time.time())

    async def _build_one(self, name: str, version: str, robot_type: str) -> None:
        from ontology.package import unpack_package

        from .sandbox import Sandbox
        from .store_build import BUILD_TIMEOUT_S, run_tests

        try:
            dl = await self._repo(self.repo.download, name, version)
        except StoreError:
            return  # deleted meanwhile
        started = time.time()
        await self._repo(self.repo.set_build, name, version, robot_type, S.BuildState.BUILDING, started=started)
        self.record_structure("build", rapp=name, version=version, robot_type=robot_type, state="building")
        workdir = self.build_dir / f"{next(self._build_serial):04d}-{name}-{version}-{robot_type}"
        try:
            await asyncio.to_thread(unpack_package, dl.data, workdir / "package")
            if self._sandbox is None:
                self._sandbox = await asyncio.to_thread(Sandbox)
            result = await run_tests(workdir / "package", robot_type, workdir, self._sandbox,
                                     timeout_s=self.build_timeout_s or BUILD_TIMEOUT_S)
        finally:
            await asyncio.to_thread(shutil.rmtree, workdir, True)
        await self._repo(self.repo.set_build, name, version, robot_type, result.state, result.reason,
                         log=result.log, ended=time.time())
        self.record_structure("build", rapp=name, version=version, robot_type=robot_type, state=result.state,
                              reason=result.reason[:300], seconds=round(time.time() - started, 1))
        if result.state == S.BuildState.PASSED:
            await self._tell_subscribers("published", name, [version], [robot_type])

    async def builds(self, req: S.Builds, ctx) -> S.BuildList:
        return S.BuildList(builds=[_build(b) for b in await self._repo(self.repo.builds, req.name, req.version)])

    async def build_log(self, req: S.BuildLog, ctx) -> S.BuildLogText:
        text = await self._repo(self.repo.build_log, req.name, req.version, req.robot_type)
        return S.BuildLogText(name=req.name, version=req.version, robot_type=req.robot_type, log=text)

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
