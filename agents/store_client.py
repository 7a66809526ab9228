"""Client side of the Store protocol: download (verified) and publish in chunks."""
from __future__ import annotations

from ontology import store as S
from ontology.chunks import Reassembler, split_chunks
from ontology.errors import ErrorCode
from ontology.package import sha256_hex

from .base import RappAgent
from .errors import RequestFailed


async def download_package(agent: RappAgent, store: str, name: str, version: str | None = None,
                           timeout: float = 10.0, token: str = "") -> tuple[S.DownloadInfo, bytes]:
    """The package bytes, reassembled and checked against the Store's sha256. `token`: the
    sender's Platform token (the Store refuses downloads without one, except to the Platform)."""
    info = await agent.request(store, S.DownloadBegin(name=name, version=version, token=token), timeout=timeout)
    assembler = Reassembler(total=info.chunks, sha256=info.sha256, size=info.size)
    for i in range(info.chunks):
        chunk = await agent.request(store, S.DownloadChunk(name=info.name, version=info.version, index=i,
                                                                    token=token),
                                    timeout=timeout)
        assembler.add(chunk.model_dump())
    data = assembler.result()
    if sha256_hex(data) != info.sha256:  # Reassembler checks too; keep the contract explicit
        raise RequestFailed(f"package {name} failed its sha256 check", code=ErrorCode.SHA256_MISMATCH)
    return info, data


async def publish_package(agent: RappAgent, store: str, owner: str, password: str, data: bytes,
                          timeout: float = 10.0) -> S.PackageDetails:
    upload_id = None
    for chunk in split_chunks(data):
        ticket = await agent.request(store, S.UploadChunk(upload_id=upload_id,
                                                          chunk=S.ChunkData(**chunk.model_dump())),
                                     timeout=timeout)
        upload_id = ticket.upload_id
    return await agent.request(store, S.Publish(owner=owner, password=password, upload_id=upload_id),
                               timeout=timeout)
