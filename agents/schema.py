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

import sqlite3
from collections.abc import Callable, Sequence

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
