"""Persistent Store repository."""
from __future__ import annotations

import sqlite3

import pytest

from agents.store_repository import StoreError, StoreRepository
from ontology.package import build_package_bytes, generate_keypair, read_package
from tests.rapps.helpers import make_src


@pytest.fixture
def build(tmp_path):
    counter = iter(range(10_000))

    def _build(signing_key=None, **overrides) -> bytes:
        return build_package_bytes(make_src(tmp_path / f"src{next(counter)}", **overrides), signing_key)
    return _build


@pytest.fixture
def repo(tmp_path):
    r = StoreRepository(tmp_path / "store")
    r.register_owner("alice", password="pw-a")
    r.register_owner("bob", password="pw-b")
    yield r
    r.close()


def _code(exc_info) -> str:
    return exc_info.value.code


def test_owners_and_robots(repo):
    assert repo.verify_owner("alice", "pw-a") and not repo.verify_owner("alice", "nope")
    assert not repo.verify_owner("nobody", "pw-a")
    with pytest.raises(StoreError) as exc:
        repo.register_owner("alice", password="x")
    assert _code(exc) == "duplicate"
    assert repo.register_robot("nao-1", "nao", "alice").robot_type == "nao"
    repo.register_robot("nao-1", "nao", "alice")  # idempotent re-registration
    with pytest.raises(StoreError) as exc:
        repo.register_robot("nao-1", "nao", "bob")
    assert _code(exc) == "forbidden"
    with pytest.raises(StoreError) as exc:
        repo.register_robot("r2", "toaster", "alice")
    assert _code(exc) == "invalid"
    with pytest.raises(StoreError) as exc:
        repo.register_robot("r2", "nao", "carol")
    assert _code(exc) == "not_found"
    assert [r.robot_id for r in repo.robots("alice")] == ["nao-1"]
    assert repo.get_robot("nao-1").owner == "alice"


def test_publish_list_filter_search(repo, build):
    repo.publish("alice", build(name="wave", keywords=["wave"], robot_types=["nao"]))
    repo.publish("alice", build(name="patrol", keywords=["patrol"], robot_types=["elektron"],
                                description="Drive around looking for hazards", entry_point="p.main:Patrol"))
    repo.publish("bob", build(name="greet", keywords=["hello"], robot_types=["nao", "elektron"],
                              phrases=["say hello to grandma"]))
    assert [s.name for s in repo.list()] == ["greet", "patrol", "wave"]
    assert [s.name for s in repo.list("nao")] == ["greet", "wave"]
    assert [s.name for s in repo.list("elektron")] == ["greet", "patrol"]
    s = repo.list()[0]
    assert s.keywords == ["hello"] and s.robot_types == ["nao", "elektron"] and s.size > 0 and len(s.sha256) == 64
    assert [s.name for s in repo.search("HAZARDS")] == ["patrol"]  # description, case-insensitive
    assert [s.name for s in repo.search("grandma")] == ["greet"]  # phrases
    # exact keyword match first, then the others whose default phrase "wave your hand" matches
    assert [s.name for s in repo.search("wave")] == ["wave", "greet", "patrol"]
    assert [s.name for s in repo.search("hello", robot_type="elektron")] == ["greet"]
    assert repo.search("nothing-like-this") == []
    assert repo.vocabulary("nao") == {"hello": "greet", "wave": "wave"}
    with pytest.raises(StoreError) as exc:
        repo.list("toaster")
    assert _code(exc) == "invalid"


def test_versions_info_download_latest(repo, build):
    for v in ("1.2.0", "1.10.0", "1.9.3"):
        repo.publish("alice", build(version=v, description=f"v{v}"))
    assert repo.versions("demo") == ["1.10.0", "1.9.3", "1.2.0"]
    assert repo.list()[0].version == "1.10.0"  # numeric, not upload order
    info = repo.info("demo")
    assert info.version == "1.10.0" and info.owner == "alice" and info.versions == repo.versions("demo")
    assert repo.info("demo", "1.2.0").description == "v1.2.0"
    d = repo.download("demo")
    assert d.manifest.version == "1.10.0"
    assert read_package(d.data).sha256 == d.sha256 == info.sha256
    manifest, data, sha = repo.download("demo", "1.2.0")
    assert manifest.version == "1.2.0" and read_package(data).manifest.description == "v1.2.0"
    assert repo.info("demo", "1.10.0").downloads == 1
    for call in (lambda: repo.info("nope"), lambda: repo.info("demo", "9.9.9"), lambda: repo.versions("nope"),
                 lambda: repo.download("nope"), lambda: repo.download("demo", "0.0.1")):
        with pytest.raises(StoreError) as exc:
            call()
        assert _code(exc) == "not_found"


def test_latest_per_robot_type(repo, build):
    repo.publish("alice", build(version="1.0.0", robot_types=["nao", "elektron"]))
    repo.publish("alice", build(version="2.0.0", robot_types=["elektron"]))
    assert repo.list("nao")[0].version == "1.0.0"
    assert repo.list("elektron")[0].version == "2.0.0"


def test_publish_refusals(repo, build):
    data = build()
    repo.publish("alice", data)
    with pytest.raises(StoreError) as exc:
        repo.publish("alice", data)
    assert _code(exc) == "duplicate"
    with pytest.raises(StoreError) as exc:
        repo.publish("bob", build(version="2.0.0"))  # name owned by alice
    assert _code(exc) == "forbidden"
    with pytest.raises(StoreError) as exc:
        repo.publish("mallory", build(name="other"))
    assert _code(exc) == "forbidden"
    with pytest.raises(StoreError, match="corrupt") as exc:
        repo.publish("alice", b"garbage")
    assert _code(exc) == "invalid_package"
    assert repo.versions("demo") == ["1.0.0"]


def test_signed_publish_records_key(repo, build):
    key, pub = generate_keypair()
    other, _ = generate_keypair()
    info = repo.publish("alice", build(key, name="signed"))
    assert info.signer_public_key == pub and info.signer_key_id and repo.download("signed").data
    repo.register_owner("dev", public_key=pub)
    with pytest.raises(StoreError) as exc:
        repo.publish("dev", build(other, name="devapp"))
    assert _code(exc) == "forbidden"
    with pytest.raises(StoreError):
        repo.publish("dev", build(name="devapp"))  # unsigned
    assert repo.publish("dev", build(key, name="devapp")).signer_public_key == pub
    strict = StoreRepository(repo.data_dir / "strict", require_signature=True)
    strict.register_owner("alice")
    with pytest.raises(StoreError) as exc:
        strict.publish("alice", build())
    assert _code(exc) == "invalid_package"
    strict.close()


def test_delete_by_owner_only(repo, build):
    repo.publish("alice", build(version="1.0.0"))
    repo.publish("alice", build(version="1.1.0"))
    sha_old = repo.info("demo", "1.0.0").sha256
    with pytest.raises(StoreError) as exc:
        repo.delete("demo", owner="bob")
    assert _code(exc) == "forbidden" and "owner" in str(exc.value)
    assert repo.delete("demo", "1.0.0", owner="alice") == ["1.0.0"]
    assert not repo.blob_path(sha_old).exists()
    assert repo.versions("demo") == ["1.1.0"]
    with pytest.raises(StoreError) as exc:
        repo.delete("demo", "1.0.0", owner="alice")
    assert _code(exc) == "not_found"
    sha_new = repo.info("demo").sha256
    assert repo.delete("demo", owner="alice") == ["1.1.0"]
    assert repo.list() == [] and not repo.blob_path(sha_new).exists()
    repo.publish("bob", build(version="3.0.0"))  # the name is free again
    assert repo.info("demo").owner == "bob"


def test_survives_reopen(tmp_path, build):
    r = StoreRepository(tmp_path / "s")
    r.register_owner("alice", password="pw")
    r.register_robot("e1", "elektron", "alice")
    key, pub = generate_keypair()
    data = build(key, robot_types=["elektron"])
    r.publish("alice", data)
    r.close()
    with StoreRepository(tmp_path / "s") as again:
        assert again.verify_owner("alice", "pw")
        assert again.get_robot("e1").robot_type == "elektron"
        assert [s.name for s in again.list("elektron")] == ["demo"]
        assert again.download("demo").data == data
        assert again.info("demo").signer_public_key == pub
        mode = sqlite3.connect(tmp_path / "s" / "store.db").execute("PRAGMA journal_mode").fetchone()[0]
        assert mode == "wal"


def test_damaged_blob_reported(repo, build):
    repo.publish("alice", build())
    path = repo.blob_path(repo.info("demo").sha256)
    assert path.parent.name == path.name[:2]
    path.write_bytes(b"bitrot")
    with pytest.raises(StoreError) as exc:
        repo.download("demo")
    assert _code(exc) == "corrupt"


def test_concurrent_calls_from_threads(repo, build):
    """The agent calls the repository through asyncio.to_thread: several threads at once."""
    import asyncio

    datas = [build(name=f"app{i}", keywords=[f"kw{i}"]) for i in range(6)]

    async def main():
        await asyncio.gather(*(asyncio.to_thread(repo.publish, "alice", d) for d in datas))
        return await asyncio.gather(*(asyncio.to_thread(repo.download, f"app{i}") for i in range(6)),
                                    *(asyncio.to_thread(repo.list) for _ in range(6)))

    results = asyncio.run(main())
    assert [r.data for r in results[:6]] == datas
    assert all(len(r) == 6 for r in results[6:])
