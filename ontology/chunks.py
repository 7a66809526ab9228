"""Transfer of large byte strings (packages) over XMPP as base64 chunks.

`split_chunks` cuts bytes into `Chunk` records of at most ``chunk_size`` raw bytes; each carries
its ``index``, the ``total`` count, the ``sha256`` and ``size`` of the whole payload, and the
``part_sha256`` of its own bytes, so a corrupted chunk is detected on arrival. `Reassembler`
accepts chunks in any order, refuses inconsistent/corrupt/duplicate-but-different chunks and
oversize transfers with `ChunkError`, and `result()` returns the bytes only once complete and the
final sha256 matches.
"""
from __future__ import annotations

import base64
import binascii
import hashlib
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError
from .errors import ErrorCode

CHUNK_RAW_SIZE = 48 * 1024  # raw bytes per chunk: ~64 KiB of base64, fits an XMPP stanza
DEFAULT_MAX_TRANSFER = 64 * 1024 * 1024


class ChunkError(ValueError):
    """A chunk or a reassembled transfer is invalid; ``code`` is a short reason."""

    def __init__(self, message: str, code: str = ErrorCode.BAD_CHUNK) -> None:
        super().__init__(message)
        self.code = code


class Chunk(BaseModel):
    """One piece of a transfer (JSON-serialisable via ``model_dump()``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    index: int = Field(ge=0)
    total: int = Field(ge=1)
    size: int = Field(ge=0)  # bytes of the whole payload
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")  # of the whole payload
    part_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")  # of this chunk's raw bytes
    data: str  # base64 of this chunk's raw bytes

    @classmethod
    def parse(cls, obj: Any) -> "Chunk":
        """Validate a dict (e.g. from a message body) as a chunk; `ChunkError` if malformed."""
        if isinstance(obj, Chunk):
            return obj
        try:
            return cls.model_validate(obj)
        except ValidationError as exc:
            raise ChunkError(f"malformed chunk: {exc.errors()[0]['loc']}: {exc.errors()[0]['msg']}",
                             ErrorCode.MALFORMED) from None

    def raw(self) -> bytes:
        """Decoded bytes, checked against ``part_sha256``."""
        try:
            raw = base64.b64decode(self.data, validate=True)
        except (binascii.Error, ValueError):
            raise ChunkError(f"chunk {self.index}: invalid base64", ErrorCode.MALFORMED) from None
        if hashlib.sha256(raw).hexdigest() != self.part_sha256:
            raise ChunkError(f"chunk {self.index}: content does not match its sha256", ErrorCode.CORRUPT)
        return raw


def split_chunks(data: bytes, chunk_size: int = CHUNK_RAW_SIZE) -> list[Chunk]:
    """Cut ``data`` into chunks of at most ``chunk_size`` raw bytes (one empty chunk for b"")."""
    if chunk_size <= 0:
        raise ValueError("chunk_size must be positive")
    data = bytes(data)
    digest = hashlib.sha256(data).hexdigest()
    pieces = [data[i:i + chunk_size] for i in range(0, len(data), chunk_size)] or [b""]
    return [Chunk(index=i, total=len(pieces), size=len(data), sha256=digest,
                  part_sha256=hashlib.sha256(p).hexdigest(), data=base64.b64encode(p).decode())
            for i, p in enumerate(pieces)]


class Reassembler:
    """Collects the chunks of one transfer and yields the verified payload.

    The first chunk fixes ``total``, ``size`` and ``sha256`` unless given to the constructor;
    later chunks must agree. Re-sending an identical chunk is harmless; a different one with the
    same index is refused.
    """

    def __init__(self, *, total: int | None = None, sha256: str | None = None, size: int | None = None,
                 max_size: int = DEFAULT_MAX_TRANSFER) -> None:
        self.total, self.sha256, self.size = total, sha256, size
        self.max_size = max_size
        self._parts: dict[int, bytes] = {}
        self._received = 0
        if size is not None and size > max_size:
            raise ChunkError(f"transfer of {size} bytes exceeds limit {max_size}", ErrorCode.TOO_LARGE)

    def add(self, chunk: Chunk | dict[str, Any]) -> bool:
        """Add one chunk; return True when the transfer is complete. `ChunkError` if invalid."""
        chunk = Chunk.parse(chunk)
        for attr in ("total", "sha256", "size"):
            expected = getattr(self, attr)
            if expected is None:
                setattr(self, attr, getattr(chunk, attr))
            elif getattr(chunk, attr) != expected:
                raise ChunkError(f"chunk {chunk.index}: {attr} {getattr(chunk, attr)!r} does not match "
                                 f"the transfer ({expected!r})", ErrorCode.MISMATCH)
        size, total = chunk.size, chunk.total  # what the transfer's now agree with
        if size > self.max_size:
            raise ChunkError(f"transfer of {size} bytes exceeds limit {self.max_size}", ErrorCode.TOO_LARGE)
        if chunk.index >= total:
            raise ChunkError(f"chunk index {chunk.index} out of range (total {self.total})", ErrorCode.OUT_OF_RANGE)
        raw = chunk.raw()
        if chunk.index in self._parts:
            if self._parts[chunk.index] != raw:
                raise ChunkError(f"chunk {chunk.index} received twice with different content", ErrorCode.DUPLICATE)
            return self.complete
        if self._received + len(raw) > size:
            raise ChunkError(f"chunks exceed the announced size {size}", ErrorCode.TOO_LARGE)
        self._parts[chunk.index] = raw
        self._received += len(raw)
        return self.complete

    @property
    def complete(self) -> bool:
        return self.total is not None and len(self._parts) == self.total

    def missing(self) -> list[int]:
        """Indexes not received yet (empty before the first chunk)."""
        if self.total is None:
            return []
        return [i for i in range(self.total) if i not in self._parts]

    def result(self) -> bytes:
        """The payload; `ChunkError` if incomplete or if its size/sha256 do not match."""
        if not self.complete:
            raise ChunkError(f"transfer incomplete: missing chunks {self.missing()[:10]}", ErrorCode.INCOMPLETE)
        data = b"".join(self._parts[i] for i in range(self.total))  # type: ignore[arg-type]
        if len(data) != self.size:
            raise ChunkError(f"reassembled {len(data)} bytes, expected {self.size}", ErrorCode.SIZE_MISMATCH)
        if hashlib.sha256(data).hexdigest() != self.sha256:
            raise ChunkError("reassembled payload does not match its sha256", ErrorCode.SHA256_MISMATCH)
        return data


def join_chunks(chunks: list[Chunk | dict[str, Any]], *, max_size: int = DEFAULT_MAX_TRANSFER) -> bytes:
    """Reassemble a full list of chunks (any order) into the verified payload."""
    r = Reassembler(max_size=max_size)
    for c in chunks:
        r.add(c)
    return r.result()
