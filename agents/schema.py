"""Schema versions of the agents' SQLite databases (the Store's, the Platform's users and its services'
data): `PRAGMA user_version` counts the migrations applied, and `migrate` applies the missing ones in
order, each in one transaction with the version it reaches, so a crash leaves the old version or the
new one, never half of a step.

A step is SQL text (statements separated by ";", no triggers) or a function of the connection. Step 1
of each database creates its tables with IF NOT EXISTS, so a file from before versions existed (at
version 0, its tables there) is adopted as it is. A file at a version above the code's is refused
untouched: an older program must not write a newer layout.
"""
from __future__ import annotations

import os
import sqlite3
from collections.abc import Callable, Sequence
from pathlib import Path

Step = str | Callable[[sqlite3.Connection], None]


class SchemaError(RuntimeError):
    """The database cannot be brought to this code's schema."""


def version(db: sqlite3.Connection) -> int:
    return int(db.execute("PRAGMA user_version").fetchone()[0])


def migrate(db: sqlite3.Connection, steps: Sequence[Step], what: str) -> tuple[int, int]:
    """Bring `db` to version len(steps); (version found, version now). `what` names the database in
    errors. The connection must not be inside a transaction."""
    found = version(db)
    if found > len(steps):
        raise SchemaError(f"{what} is at schema version {found}, newer than this program's {len(steps)}: "
                          "run the newer program, or restore a backup made for this one")
    for number in range(found + 1, len(steps) + 1):
        step = steps[number - 1]
        db.execute("BEGIN IMMEDIATE")
        try:
            if callable(step):
                step(db)
            else:
                for statement in step.split(";"):
                    if statement.strip():
                        db.execute(statement)
            db.execute(f"PRAGMA user_version = {number}")
        except BaseException as e:
            db.execute("ROLLBACK")
            if isinstance(e, sqlite3.Error):
                raise SchemaError(f"{what}: migration to schema version {number} failed ({e}); "
                                  f"the database stays at version {number - 1}") from e
            raise
        db.execute("COMMIT")
    return found, len(steps)


def open_migrated(path: Path | None, steps: Sequence[Step], what: str,
                  pragmas: Sequence[str] = ()) -> sqlite3.Connection:
    """An autocommit connection (rows as sqlite3.Row, usable from any thread under the caller's lock)
    to `path` at this code's schema; None: in memory. A file is created 0600 before SQLite opens it
    (never readable by others, not even for a moment) and runs in WAL mode, then each of `pragmas`."""
    if path is not None:
        os.close(os.open(path, os.O_CREAT | os.O_WRONLY, 0o600))
        os.chmod(path, 0o600)  # a file that existed keeps no wider mode
    db = sqlite3.connect(str(path) if path is not None else ":memory:", check_same_thread=False,
                         isolation_level=None, timeout=10)
    db.row_factory = sqlite3.Row
    try:
        if path is not None:
            db.execute("PRAGMA journal_mode=WAL")
        for pragma in pragmas:
            db.execute(f"PRAGMA {pragma}")
        migrate(db, steps, what)
    except BaseException:
        db.close()
        raise
    return db
