"""The Platform's persistent directory of users and tokens (agents/platform_users.py)."""
from __future__ import annotations

import sqlite3
import stat
import threading
import time

import pytest

from agents.platform_users import DirectoryError, TokenInfo, UserDirectory

HOLDER = "alice@localhost"
CORE = "core-r1@localhost"


def _mode(path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def _token_rows(db_path) -> int:
    with sqlite3.connect(db_path) as db:
        return db.execute("SELECT COUNT(*) FROM tokens").fetchone()[0]


@pytest.fixture
def db_path(tmp_path):
    return tmp_path / "platform" / "users.db"


@pytest.fixture
def directory(db_path):
    d = UserDirectory(db_path)
    yield d
    d.close()


def test_users_and_tokens_survive_reopening(db_path):
    d = UserDirectory(db_path)
    d.add_user("alice", "s3cret")
    login, login_exp = d.issue("alice", 3600, holder=HOLDER)
    app, _ = d.issue("alice", 600, holder="cloud-1@localhost", rapp="hazard", issuer=CORE,
                     services=frozenset({"path_plan", "map_get"}))
    d.close()

    d = UserDirectory(db_path)
    try:
        assert d.has_user("alice") and not d.has_user("bob")
        assert d.check_login("alice", "s3cret")
        assert d.lookup(login) == TokenInfo("alice", login_exp, HOLDER, None, None, None)
        info = d.lookup(app)
        assert info is not None
        assert (info.user, info.holder, info.rapp, info.issuer) == ("alice", "cloud-1@localhost", "hazard", CORE)
        assert info.services == frozenset({"path_plan", "map_get"})
        with pytest.raises(DirectoryError) as e:
            d.add_user("alice", "other")
        assert e.value.code == "duplicate"
    finally:
        d.close()


def test_in_memory_directory_writes_no_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for path in (None, ":memory:"):
        d = UserDirectory(path)
        d.add_user("alice", "pw")
        token, _ = d.issue("alice", 60, holder=HOLDER)
        assert d.lookup(token).user == "alice"
        d.close()
    assert list(tmp_path.iterdir()) == []


def test_wrong_password_and_unknown_user_fail(directory):
    directory.add_user("alice", "s3cret")
    assert directory.check_login("alice", "s3cret")
    assert not directory.check_login("alice", "s3cre")
    assert not directory.check_login("alice", "")
    assert not directory.check_login("bob", "s3cret")


def test_duplicate_user_is_refused_and_keeps_the_first_password(directory):
    directory.add_user("alice", "first")
    with pytest.raises(DirectoryError) as e:
        directory.add_user("alice", "second")
    assert e.value.code == "duplicate"
    assert directory.check_login("alice", "first") and not directory.check_login("alice", "second")


@pytest.mark.parametrize("name", ["", "a" * 65, "bad name", "x/y", "al'ice", "alice\n", "élan", None, 7])
def test_invalid_user_names_are_refused(directory, name):
    with pytest.raises(DirectoryError) as e:
        directory.add_user(name, "pw")
    assert e.value.code == "invalid"
    if isinstance(name, str):
        assert not directory.has_user(name)


@pytest.mark.parametrize("name", ["a", "a" * 64, "Robot_1.home-2@lab"])
def test_valid_user_names_are_accepted(directory, name):
    directory.add_user(name, "pw")
    assert directory.has_user(name)


def test_empty_password_is_refused(directory):
    with pytest.raises(DirectoryError) as e:
        directory.add_user("alice", "")
    assert e.value.code == "invalid"
    assert not directory.has_user("alice")


def test_expired_token_gives_none_and_is_deleted(directory, db_path):
    directory.add_user("alice", "pw")
    expired, expires_at = directory.issue("alice", -1, holder=HOLDER)
    live, _ = directory.issue("alice", 3600, holder=HOLDER)
    assert expires_at < time.time()
    assert _token_rows(db_path) == 2
    assert directory.lookup(expired) is None
    assert _token_rows(db_path) == 1  # the lookup deleted it
    assert directory.lookup(live) is not None


def test_purge_expired_deletes_only_expired_tokens(directory, db_path):
    old = [directory.issue("alice", -5, holder=HOLDER)[0] for _ in range(2)]
    live, _ = directory.issue("alice", 3600, holder=HOLDER)
    assert directory.purge_expired() == 2
    assert _token_rows(db_path) == 1
    assert directory.purge_expired() == 0
    assert directory.lookup(live) is not None and all(directory.lookup(t) is None for t in old)


def test_not_after_caps_the_expiry(directory):
    now = time.time()
    _, capped = directory.issue("alice", 3600, holder=HOLDER, not_after=now + 10)
    assert capped == now + 10
    token, uncapped = directory.issue("alice", 60, holder=HOLDER, not_after=now + 3600)
    assert now + 59 < uncapped < now + 70
    assert directory.lookup(token).expires_at == uncapped
    past, _ = directory.issue("alice", 3600, holder=HOLDER, not_after=now - 1)
    assert directory.lookup(past) is None


def test_revoke(directory):
    token, _ = directory.issue("alice", 3600, holder=HOLDER)
    other, _ = directory.issue("alice", 3600, holder=HOLDER)
    assert directory.revoke(token) is True
    assert directory.lookup(token) is None
    assert directory.revoke(token) is False
    assert directory.revoke("never-issued") is False
    assert directory.lookup(other) is not None


def test_revoke_issued_by(directory):
    login, _ = directory.issue("alice", 3600, holder=HOLDER)
    a1, _ = directory.issue("alice", 3600, holder="cloud-1@localhost", rapp="a", issuer=CORE,
                            services=frozenset({"x"}))
    a2, _ = directory.issue("alice", 3600, holder="cloud-2@localhost", rapp="b", issuer=CORE,
                            services=frozenset())
    other_core, _ = directory.issue("alice", 3600, holder="cloud-1@localhost", rapp="a",
                                    issuer="core-r2@localhost", services=frozenset({"x"}))
    assert directory.revoke_issued_by(CORE, holder="cloud-1@localhost") == 1
    assert directory.lookup(a1) is None and directory.lookup(a2) is not None
    assert directory.lookup(a2).services == frozenset()  # empty scope is not "unscoped"
    assert directory.revoke_issued_by(CORE) == 1
    assert directory.lookup(a2) is None
    assert directory.revoke_issued_by(CORE) == 0
    assert directory.lookup(login) is not None and directory.lookup(other_core) is not None


def test_file_and_directory_modes(tmp_path):
    path = tmp_path / "new" / "users.db"
    d = UserDirectory(path)
    d.add_user("alice", "pw")
    d.issue("alice", 60, holder=HOLDER)
    assert _mode(path.parent) == 0o700
    assert _mode(path) == 0o600
    for side in path.parent.iterdir():  # any journal SQLite left behind
        assert _mode(side) == 0o600, side
    d.close()


def test_an_existing_loose_file_is_tightened(tmp_path):
    path = tmp_path / "users.db"
    UserDirectory(path).close()
    path.chmod(0o644)
    stale = tmp_path / "users.db-wal"  # left over by some earlier SQLite, world-readable
    stale.write_bytes(b"")
    stale.chmod(0o644)
    UserDirectory(path).close()
    assert _mode(path) == 0o600
    assert not stale.exists() or _mode(stale) == 0o600


def test_database_holds_no_token_and_no_password(db_path):
    d = UserDirectory(db_path)
    d.add_user("alice", "correct-horse-battery")
    tokens = [d.issue("alice", 3600, holder=HOLDER)[0],
              d.issue("alice", 3600, holder="c@localhost", rapp="r", issuer=CORE, services=frozenset({"s"}))[0]]
    d.close()
    data = b"".join(p.read_bytes() for p in db_path.parent.iterdir())
    assert b"alice" in data  # the check reads the real content
    assert b"correct-horse-battery" not in data
    for token in tokens:
        assert token.encode() not in data
    d = UserDirectory(db_path)
    assert all(d.lookup(t) is not None for t in tokens)  # ... yet the tokens still work
    d.close()


def test_concurrent_calls_from_threads(directory):
    directory.add_user("alice", "pw")
    issued: list[str] = []
    errors: list[BaseException] = []

    def work() -> None:
        try:
            for _ in range(25):
                token, _ = directory.issue("alice", 60, holder=HOLDER)
                assert directory.lookup(token) is not None
                issued.append(token)
        except Exception as exc:  # noqa: BLE001 - reported below, in the main thread
            errors.append(exc)

    threads = [threading.Thread(target=work) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert len(set(issued)) == 200
    assert all(directory.revoke(t) for t in issued)
