"""Schema versions with migrations (agents/schema.py, `PRAGMA user_version`) for the Store's and the
Platform's SQLite databases."""
from __future__ import annotations

import sqlite3

import pytest

from agents.platform_users import UserDirectory
from agents.schema import SchemaError, migrate, version
from agents.store_repository import MIGRATIONS, StoreRepository

# the Store's layout before owners were bound to a JID (commit 35cc9a5) and before versions were kept
_OLD_STORE = """
CREATE TABLE owners (name TEXT PRIMARY KEY, password_hash TEXT, public_key TEXT, created_at REAL NOT NULL);
CREATE TABLE robots (robot_id TEXT PRIMARY KEY, robot_type TEXT NOT NULL, owner TEXT NOT NULL REFERENCES owners(name),
    registered_at REAL NOT NULL);
CREATE TABLE packages (name TEXT PRIMARY KEY, owner TEXT NOT NULL REFERENCES owners(name), created_at REAL NOT NULL);
INSERT INTO owners VALUES ('alice', NULL, NULL, 1.0);
"""


def test_a_store_from_before_versions_is_adopted_and_keeps_its_data(tmp_path):
    db = sqlite3.connect(tmp_path / "store.db")
    db.executescript(_OLD_STORE)
    db.close()
    repo = StoreRepository(tmp_path)
    assert version(repo._db) == len(MIGRATIONS)
    tables = {r[0] for r in repo._db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert {"owners", "versions", "owner_jids"} <= tables
    assert repo.register_robot("nao1", "nao", "alice").owner == "alice"  # the old owner row is there
    repo.close()


def test_a_newer_store_or_users_database_is_refused_untouched(tmp_path):
    StoreRepository(tmp_path).close()
    db = sqlite3.connect(tmp_path / "store.db")
    db.execute(f"PRAGMA user_version = {len(MIGRATIONS) + 1}")
    db.commit()
    db.close()
    with pytest.raises(SchemaError, match="newer than this program's"):
        StoreRepository(tmp_path)
    UserDirectory(tmp_path / "users.db").close()
    db = sqlite3.connect(tmp_path / "users.db")
    db.execute("PRAGMA user_version = 7")
    db.commit()
    db.close()
    with pytest.raises(SchemaError, match="users database .* schema version 7"):
        UserDirectory(tmp_path / "users.db")


def test_steps_run_in_order_and_a_failed_one_leaves_the_version_before_it():
    db = sqlite3.connect(":memory:", isolation_level=None)
    steps = ["CREATE TABLE t (a INTEGER); INSERT INTO t VALUES (1)",
             lambda c: c.execute("ALTER TABLE t ADD COLUMN b TEXT DEFAULT 'x'")]
    assert migrate(db, steps, "test db") == (0, 2)
    assert db.execute("SELECT a, b FROM t").fetchall() == [(1, "x")]
    assert migrate(db, steps, "test db") == (2, 2)  # nothing to do
    broken = steps + ["INSERT INTO t VALUES (2, 'y'); INSERT INTO nowhere VALUES (3)"]
    with pytest.raises(SchemaError, match="migration to schema version 3 failed .* stays at version 2"):
        migrate(db, broken, "test db")
    assert version(db) == 2 and db.execute("SELECT count(*) FROM t").fetchone()[0] == 1
