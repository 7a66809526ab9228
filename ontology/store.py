"""Store Agent messages: owners and robots, publishing, listing, search, download in chunks, and the
per-robot builds of what is published (agents/store_build.py)."""
from __future__ import annotations

from enum import StrEnum
from typing import Literal, Any

from pydantic import Field

from .registry import Action, Content, Done, action

ONTOLOGY = "store"


class PackageSummary(Content):
    name: str
    version: str
    description: str = ""
    robot_types: list[str]
    keywords: list[str] = []
    phrases: list[str] = []
    sha256: str
    size: int


class PackageList(Content):
    packages: list[PackageSummary]


class BuildState(StrEnum):
    """A version's build for one robot type (paper 000 sec. 6.2: the Store builds each RApp per robot)."""

    QUEUED = "queued"  # published, its build not begun
    BUILDING = "building"  # its tests run in the sandbox for the type
    PASSED = "passed"  # they passed: listed for the type
    FAILED = "failed"  # they failed (or it does not compile): not listed for the type, with the reason
    UNTESTED = "untested"  # no tests (or the Store builds nothing): compiled only, listed for the type


LISTED = (BuildState.PASSED, BuildState.UNTESTED)  # the states a version is offered to a robot type in


class BuildInfo(Content):
    name: str
    version: str
    robot_type: str
    state: BuildState
    reason: str = ""  # failed: why the type was refused; untested: why nothing ran
    started: float | None = None
    ended: float | None = None
    log_size: int = 0  # characters of its log kept (`build_log`)


class BuildList(Content):
    builds: list[BuildInfo]


class BuildLogText(Content):
    name: str
    version: str
    robot_type: str
    log: str


class PackageDetails(Content):
    summary: PackageSummary
    owner: str
    manifest: dict[str, Any]
    signer_key_id: str | None = None
    versions: list[str] = []
    builds: list[BuildInfo] = []  # this version's, one per robot type its manifest declares


class DownloadInfo(Content):
    name: str
    version: str
    sha256: str
    size: int
    chunks: int
    manifest: dict[str, Any]


class ChunkData(Content):
    index: int
    total: int
    size: int
    sha256: str
    part_sha256: str
    data: str  # base64


class UploadTicket(Content):
    upload_id: str


class Versions(Content):
    name: str
    versions: list[str]


class Deleted(Content):
    name: str
    versions: list[str]


@action("register_owner", ontology=ONTOLOGY, reply=Done, group="owners")
class RegisterOwner(Action):
    owner: str = Field(min_length=1, max_length=64)
    password: str = Field(min_length=1, max_length=256)
    public_key: str | None = None


@action("register_robot", ontology=ONTOLOGY, reply=Done, group="owners")
class RegisterRobot(Action):
    robot_id: str = Field(min_length=1, max_length=128)
    robot_type: str
    owner: str
    token: str = ""  # the sender's Platform login token, as `owner` (a RApp's is refused)


@action("list_packages", ontology=ONTOLOGY, reply=PackageList, group="catalogue", idempotent=True)
class ListPackages(Action):
    robot_type: str | None = None


@action("search", ontology=ONTOLOGY, reply=PackageList, group="catalogue", idempotent=True)
class Search(Action):
    keyword: str = Field(min_length=1, max_length=200)
    robot_type: str | None = None


@action("info", ontology=ONTOLOGY, reply=PackageDetails, group="catalogue", idempotent=True)
class Info(Action):
    name: str
    version: str | None = None


@action("versions", ontology=ONTOLOGY, reply=Versions, group="catalogue", idempotent=True)
class GetVersions(Action):
    name: str


@action("download_info", ontology=ONTOLOGY, reply=DownloadInfo, group="download", idempotent=True)
class DownloadBegin(Action):
    name: str
    version: str | None = None
    token: str = ""  # a Platform token held by the sender (the Platform itself needs none)


@action("download_chunk", ontology=ONTOLOGY, reply=ChunkData, group="download", idempotent=True)
class DownloadChunk(Action):
    name: str
    version: str
    index: int = Field(ge=0)
    token: str = ""


@action("upload_chunk", ontology=ONTOLOGY, reply=UploadTicket, group="publish")
class UploadChunk(Action):
    """Chunks of a package to publish; the first has no upload_id, the Store returns one."""

    upload_id: str | None = None
    chunk: ChunkData


@action("publish", ontology=ONTOLOGY, reply=PackageDetails, group="publish")
class Publish(Action):
    owner: str
    password: str
    upload_id: str


@action("delete", ontology=ONTOLOGY, reply=Deleted, group="publish")
class Delete(Action):
    owner: str
    password: str
    name: str
    version: str | None = None


@action("builds", ontology=ONTOLOGY, reply=BuildList, group="builds", idempotent=True)
class Builds(Action):
    """Every build the Store keeps (of one package, or of all; of one version, or of all)."""

    name: str | None = None
    version: str | None = None


@action("build_log", ontology=ONTOLOGY, reply=BuildLogText, group="builds", idempotent=True)
class BuildLog(Action):
    name: str
    version: str
    robot_type: str


@action("subscribe_catalogue", ontology=ONTOLOGY, reply=Done, group="catalogue")
class SubscribeCatalogue(Action):
    """FIPA subscribe (performative subscribe): the sender is told of every publish and removal
    (`catalogue_changed` notifications) until it logs out."""

    robot_type: str | None = None


@action("catalogue_changed", ontology=ONTOLOGY, reply=Done, group="catalogue")
class CatalogueChanged(Action):
    """Notification to subscribers: a RApp version was published or removed."""

    event: Literal["published", "removed"]
    name: str
    versions: list[str] = []
