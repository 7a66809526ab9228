"""Chunked transfer of packages."""
from __future__ import annotations

import base64
import hashlib
import random

import pytest
from hypothesis import given, settings, strategies as st

from ontology.chunks import CHUNK_RAW_SIZE, Chunk, ChunkError, Reassembler, join_chunks, split_chunks


def test_round_trip_any_order():
    data = random.Random(1).randbytes(3 * CHUNK_RAW_SIZE + 17)
    chunks = split_chunks(data)
    assert len(chunks) == 4 and all(c.total == 4 for c in chunks)
    assert all(len(base64.b64decode(c.data)) <= CHUNK_RAW_SIZE for c in chunks)
    r = Reassembler()
    shuffled = chunks[:]
    random.Random(2).shuffle(shuffled)
    done = [r.add(c.model_dump()) for c in shuffled]  # as dicts, like a message body
    assert done == [False, False, False, True]
    assert r.result() == data
    assert chunks[0].sha256 == hashlib.sha256(data).hexdigest()


def test_empty_payload():
    chunks = split_chunks(b"")
    assert len(chunks) == 1
    assert join_chunks(chunks) == b""


def test_incomplete_and_missing():
    chunks = split_chunks(b"x" * 100, chunk_size=10)
    r = Reassembler()
    for c in chunks[:-2]:
        r.add(c)
    assert r.missing() == [8, 9]
    with pytest.raises(ChunkError, match="incomplete") as exc:
        r.result()
    assert exc.value.code == "incomplete"


def test_corrupted_chunk_detected():
    chunks = split_chunks(b"abcdefghij" * 10, chunk_size=10)
    bad = chunks[3].model_copy(update={"data": base64.b64encode(b"XXXXXXXXXX").decode()})
    with pytest.raises(ChunkError, match="sha256") as exc:
        Reassembler().add(bad)
    assert exc.value.code == "corrupt"


def test_consistent_but_wrong_payload_detected():
    """Chunks each self-consistent but announcing the sha256 of other data."""
    data, other = b"a" * 30, b"b" * 30
    forged = [c.model_copy(update={"sha256": hashlib.sha256(other).hexdigest()}) for c in split_chunks(data, 10)]
    with pytest.raises(ChunkError) as exc:
        join_chunks(forged)
    assert exc.value.code == "sha256_mismatch"


def test_mismatch_duplicate_range_and_malformed():
    a = split_chunks(b"1" * 30, 10)
    b = split_chunks(b"2" * 40, 10)
    r = Reassembler()
    r.add(a[0])
    assert r.add(a[0]) is False  # identical resend is harmless
    with pytest.raises(ChunkError) as exc:
        r.add(b[1])
    assert exc.value.code == "mismatch"
    forged = a[1].model_copy(update={"index": 7})
    with pytest.raises(ChunkError, match="out of range"):
        r.add(forged)
    other = split_chunks(b"3" * 30, 10)[0].model_copy(update={"sha256": a[0].sha256})
    with pytest.raises(ChunkError) as exc:
        r.add(other)
    assert exc.value.code == "duplicate"
    with pytest.raises(ChunkError, match="malformed"):
        r.add({"index": -1})
    with pytest.raises(ChunkError, match="base64"):
        Chunk(**{**a[2].model_dump(), "data": "!!!"}).raw()


def test_size_limit():
    chunks = split_chunks(b"z" * 100, 10)
    with pytest.raises(ChunkError) as exc:
        Reassembler(max_size=50).add(chunks[0])
    assert exc.value.code == "too-large"


@settings(max_examples=50, deadline=None)
@given(st.binary(max_size=5000), st.integers(1, 700))
def test_property_round_trip(data, size):
    assert join_chunks(list(reversed(split_chunks(data, size)))) == data
