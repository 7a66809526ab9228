"""The Platform's users and tokens, in SQLite: they survive a Platform restart.

Passwords are kept as scrypt hashes and tokens only as SHA-256 hashes, so a copy of the database
gives no password and no live token (a token is 24 random bytes: its hash cannot be reversed or
guessed). The file is 0600 in a 0700 directory all the same: user names, holders and expiry times
are nobody else's business, and no other local user may replace or corrupt the directory. Every
token names its holder, the one JID the Platform accepts it from. Methods are synchronous and
thread-safe (one connection guarded by a lock), meant to be called via ``asyncio.to_thread``.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import secrets
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from ontology.errors import ErrorCode

from .schema import open_migrated
from .store_repository import _check_password, hash_password

_USER = re.compile(r"[A-Za-z0-9._@-]{1,64}")
_SCHEMA = """
CREATE TABLE IF NOT EXISTS users (name TEXT PRIMARY KEY, password_hash TEXT NOT NULL, created REAL);
CREATE TABLE IF NOT EXISTS tokens (digest TEXT PRIMARY KEY, user TEXT NOT NULL, expires REAL NOT NULL,
    holder TEXT NOT NULL, rapp TEXT, services TEXT, issuer TEXT);
CREATE INDEX IF NOT EXISTS tokens_issuer ON tokens(issuer);
"""
_SIDECARS = ("-wal", "-shm", "-journal")


class DirectoryError(Exception):
    """A directory operation was refused; ``code`` is "duplicate" or "invalid"."""

    def __init__(self, message: str, code: str = ErrorCode.INVALID) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class TokenInfo:
    """What the directory knows of a live token."""

    user: str
    expires_at: float  # time.time() scale
    holder: str  # the only JID the token is accepted from
    rapp: str | None  # app tokens: the RApp run it was issued for
    services: frozenset[str] | None  # None: a user's own (unscoped) login token
    issuer: str | None  # app tokens: the JID that asked for it (the Core)


def _digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


class UserDirectory:
    """Users and tokens in the SQLite file ``path`` (None: in memory, lost on close)."""

    def __init__(self, path: str | os.PathLike | None) -> None:
        self.path = None if path is None or str(path) in ("", ":memory:") else Path(path)
        if self.path is not None:
            parent = self.path.parent
            if not parent.exists():
                parent.mkdir(mode=0o700, parents=True, exist_ok=True)
                os.chmod(parent, 0o700)  # mkdir's mode is filtered by the umask
        # a commit per token issued or revoked (each Cloud Agent start and stop): the write-ahead log
        # without an fsync per commit keeps the file consistent after a crash and lets a power cut
        # lose only the last tokens, at a twentieth of an fsync's cost per token
        self._db = open_migrated(self.path, (_SCHEMA,), f"the Platform's users database {self.path or ':memory:'}",
                                 pragmas=("synchronous=NORMAL",) if self.path is not None else ())
        self._lock = threading.Lock()
        if self.path is not None:  # SQLite gives its journals the database's mode; make sure
            for suffix in _SIDECARS:
                side = self.path.with_name(self.path.name + suffix)
                if side.exists():
                    os.chmod(side, 0o600)

    def close(self) -> None:
        """Close the database (the directory is unusable afterwards)."""
        with self._lock:
            self._db.close()

    def _run(self, sql: str, args: tuple = ()) -> tuple[list[tuple], int]:
        """One statement, committed on return (autocommit): (rows, rowcount)."""
        with self._lock:
            cursor = self._db.execute(sql, args)
            return cursor.fetchall(), cursor.rowcount

    # -- users ------------------------------------------------------------------------------
    def add_user(self, user: str, password: str) -> None:
        """Register ``user``; "invalid" for a bad name or password, "duplicate" if taken."""
        if not isinstance(user, str) or not _USER.fullmatch(user):
            raise DirectoryError(f"invalid user name {user!r} (1-64 letters, digits, . _ @ -)")
        if not isinstance(password, str) or not password:
            raise DirectoryError("a password is required")
        hashed = hash_password(password)
        try:
            self._run("INSERT INTO users VALUES (?,?,?)", (user, hashed, time.time()))
        except sqlite3.IntegrityError:
            raise DirectoryError(f"user {user!r} already registered", ErrorCode.DUPLICATE) from None

    def has_user(self, user: str) -> bool:
        return bool(self._run("SELECT 1 FROM users WHERE name=?", (user,))[0])

    def check_login(self, user: str, password: str) -> bool:
        """True iff the user exists and the password matches (constant-time comparison)."""
        rows = self._run("SELECT password_hash FROM users WHERE name=?", (user,))[0]
        return bool(rows) and _check_password(password, rows[0][0])

    # -- tokens -----------------------------------------------------------------------------
    def issue(self, user: str, ttl_s: float, *, holder: str, rapp: str | None = None,
              services: frozenset[str] | None = None, issuer: str | None = None,
              not_after: float | None = None) -> tuple[str, float]:
        """A new token for ``user``, usable by ``holder`` only: ``(token, expires_at)``, where
        ``expires_at`` is now + ``ttl_s``, but never later than ``not_after``."""
        token = secrets.token_urlsafe(24)
        expires = min(time.time() + ttl_s, not_after if not_after is not None else float("inf"))
        scope = None if services is None else json.dumps(sorted(services))
        self._run("INSERT INTO tokens VALUES (?,?,?,?,?,?,?)",
                  (_digest(token), user, expires, holder, rapp, scope, issuer))
        return token, expires

    def lookup(self, token: str) -> TokenInfo | None:
        """The token's record; None if unknown or expired (an expired token is deleted)."""
        rows = self._run("SELECT user, expires, holder, rapp, services, issuer FROM tokens WHERE digest=?",
                         (_digest(token),))[0]
        if not rows:
            return None
        user, expires, holder, rapp, scope, issuer = rows[0]
        if time.time() > expires:
            self.revoke(token)
            return None
        services = None if scope is None else frozenset(json.loads(scope))
        return TokenInfo(user, expires, holder, rapp, services, issuer)

    def revoke(self, token: str) -> bool:
        """Delete a token; False if it was unknown."""
        return self._run("DELETE FROM tokens WHERE digest=?", (_digest(token),))[1] > 0

    def revoke_issued_by(self, issuer: str, holder: str | None = None) -> int:
        """Delete the app tokens ``issuer`` asked for (only those for ``holder`` if given)."""
        if holder is None:
            return self._run("DELETE FROM tokens WHERE issuer=?", (issuer,))[1]
        return self._run("DELETE FROM tokens WHERE issuer=? AND holder=?", (issuer, holder))[1]

    def purge_expired(self) -> int:
        """Delete every expired token; how many."""
        return self._run("DELETE FROM tokens WHERE expires < ?", (time.time(),))[1]
