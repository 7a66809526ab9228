"""Store Agent messages: owners and robots, publishing, listing, search, download in chunks."""
from __future__ import annotations

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


class PackageDetails(Content):
    summary: PackageSummary
    owner: str
    manifest: dict[str, Any]
    signer_key_id: str | None = None
    versions: list[str] = []


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
