"""Persistent repository of the RAPP Store: owners, robots and published RApp packages.

Storage (all under ``data_dir``): SQLite ``store.db`` in WAL mode holding metadata and each
version's builds (one per robot type it declares: state, reason, log; agents/store_build.py), and
the package archives as content-addressed blobs ``blobs/<sha256[:2]>/<sha256>``. A version is
listed for a robot type only where its build for that type passed (or had nothing to run:
"untested"). Everything survives
a restart (open a new `StoreRepository` on the same directory). Methods are synchronous, short
and thread-safe (one connection guarded by a lock), meant to be called via ``asyncio.to_thread``.
Every refusal raises `StoreError` with a ``code``: "not_found", "duplicate", "forbidden",
"invalid_package", "invalid" (bad argument) or "corrupt" (blob damaged on disk).

"Latest" always means the highest ``MAJOR.MINOR.PATCH``, not the most recent upload.
"""
from __future__ import annotations

import hashlib
import hmac
import json
import os
import sqlite3
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

from pydantic import BaseModel

from ontology.manifest import ROBOT_TYPES, Manifest, version_key
from ontology.package import (DEFAULT_MAX_SIZE, Package, PackageError, load_public_key, public_key_b64,
                           read_package, sha256_hex)
from ontology.errors import ErrorCode
from .schema import open_migrated


_SCHEMA = """
CREATE TABLE IF NOT EXISTS owners (
    name TEXT PRIMARY KEY,
    password_hash TEXT,
    public_key TEXT,
    created_at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS robots (
    robot_id TEXT PRIMARY KEY,
    robot_type TEXT NOT NULL,
    owner TEXT NOT NULL REFERENCES owners(name),
    registered_at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS packages (
    name TEXT PRIMARY KEY,
    owner TEXT NOT NULL REFERENCES owners(name),
    created_at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS versions (
    name TEXT NOT NULL REFERENCES packages(name),
    version TEXT NOT NULL,
    major INTEGER NOT NULL, minor INTEGER NOT NULL, patch INTEGER NOT NULL,
    description TEXT NOT NULL,
    robot_types TEXT NOT NULL,
    keywords TEXT NOT NULL,
    phrases TEXT NOT NULL,
    manifest TEXT NOT NULL,
    sha256 TEXT NOT NULL,
    size INTEGER NOT NULL,
    signer_key_id TEXT,
    signer_public_key TEXT,
    published_by TEXT NOT NULL,
    published_at REAL NOT NULL,
    downloads INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (name, version)
);
CREATE INDEX IF NOT EXISTS versions_sha ON versions(sha256);
CREATE TABLE IF NOT EXISTS owner_jids (
    owner TEXT PRIMARY KEY REFERENCES owners(name),
    jid TEXT NOT NULL
);
"""
_BUILDS = """
CREATE TABLE builds (
    name TEXT NOT NULL,
    version TEXT NOT NULL,
    robot_type TEXT NOT NULL,
    state TEXT NOT NULL,
    reason TEXT NOT NULL DEFAULT '',
    log TEXT NOT NULL DEFAULT '',
    started REAL,
    ended REAL,
    PRIMARY KEY (name, version, robot_type),
    FOREIGN KEY (name, version) REFERENCES versions(name, version)
)
"""


def _add_builds(db: sqlite3.Connection) -> None:
    """Step 2: builds per robot type; what was published before is listed as it was (untested)."""
    db.execute(_BUILDS)
    for name, version, types in db.execute("SELECT name, version, robot_types FROM versions").fetchall():
        for robot_type in json.loads(types):
            db.execute("INSERT INTO builds (name, version, robot_type, state, reason) VALUES (?,?,?,?,?)",
                       (name, version, robot_type, "untested", "published before the Store built packages"))


# schema versions (agents/schema.py): step 1 is the layout from before versions were kept; 2 the builds
MIGRATIONS: tuple = (_SCHEMA, _add_builds)
LISTED_STATES = ("passed", "untested")  # ontology.store.LISTED
MAX_LOG = 64 * 1024
_VERSION_COLS = ("name, version, description, robot_types, keywords, phrases, manifest, sha256, size, "
                 "signer_key_id, signer_public_key, published_by, published_at, downloads")
_ORDER = "major DESC, minor DESC, patch DESC"


class StoreError(Exception):
    """A Store operation was refused; ``code`` is the machine-readable reason."""

    def __init__(self, message: str, code: str = ErrorCode.INVALID) -> None:
        super().__init__(message)
        self.code = code


class Owner(BaseModel):
    """A registered owner / developer (no secrets exposed)."""

    name: str
    public_key: str | None = None
    has_password: bool = False


class Robot(BaseModel):
    """A registered robot."""

    robot_id: str
    robot_type: str
    owner: str


class PackageSummary(BaseModel):
    """One line of `list`/`search`: a package at one (usually its latest) version."""

    name: str
    version: str
    description: str
    robot_types: list[str]
    keywords: list[str]
    phrases: list[str]
    sha256: str
    size: int


class PackageInfo(PackageSummary):
    """Full details of one published version (`info`)."""

    owner: str
    manifest: dict[str, Any]
    signer_key_id: str | None = None
    signer_public_key: str | None = None
    published_at: float
    downloads: int = 0
    versions: list[str] = []


class Build(BaseModel):
    """One version's build for one robot type."""

    name: str
    version: str
    robot_type: str
    state: str
    reason: str = ""
    started: float | None = None
    ended: float | None = None
    log_size: int = 0


class Download(NamedTuple):
    """Result of `download`."""

    manifest: Manifest
    data: bytes
    sha256: str


def hash_password(password: str, *, salt: bytes | None = None) -> str:
    """``scrypt$<salt hex>$<hash hex>`` of a password (for `register_owner`)."""
    salt = salt if salt is not None else os.urandom(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, n=2**14, r=8, p=1, dklen=32)
    return f"scrypt${salt.hex()}${digest.hex()}"


def _check_password(password: str, stored: str) -> bool:
    try:
        scheme, salt_hex, _ = stored.split("$")
        if scheme != "scrypt":
            return False
        return hmac.compare_digest(hash_password(password, salt=bytes.fromhex(salt_hex)), stored)
    except ValueError:
        return False


class StoreRepository:
    """Persistent Store repository rooted at ``data_dir`` (created if missing)."""

    def __init__(self, data_dir: str | os.PathLike, *, max_package_size: int = DEFAULT_MAX_SIZE,
                 require_signature: bool = False) -> None:
        self.data_dir = Path(data_dir)
        self.blob_dir = self.data_dir / "blobs"
        self.blob_dir.mkdir(parents=True, exist_ok=True)
        self.max_package_size = max_package_size
        self.require_signature = require_signature
        self._lock = threading.RLock()
        self._db = open_migrated(self.data_dir / "store.db", MIGRATIONS, f"the Store's database {self.data_dir / 'store.db'}",
                                 pragmas=("synchronous=NORMAL", "foreign_keys=ON"))

    # ------------------------------------------------------------------ plumbing
    def close(self) -> None:
        """Close the database (the repository is unusable afterwards)."""
        with self._lock:
            self._db.close()

    def __enter__(self) -> "StoreRepository":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")

    def _query(self, sql: str, args: tuple = ()) -> list[sqlite3.Row]:
        with self._lock:
            return self._db.execute(sql, args).fetchall()

    def blob_path(self, sha256: str) -> Path:
        """Where the blob with this sha256 lives."""
        return self.blob_dir / sha256[:2] / sha256

    def _write_blob(self, sha256: str, data: bytes) -> None:
        path = self.blob_path(sha256)
        if path.exists() and path.stat().st_size == len(data):
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def _drop_blob_if_unreferenced(self, sha256: str) -> None:
        with self._lock:
            if not self._query("SELECT 1 FROM versions WHERE sha256=? LIMIT 1", (sha256,)):
                self.blob_path(sha256).unlink(missing_ok=True)

    # ------------------------------------------------------------------ owners and robots
    def register_owner(self, name: str, *, password: str | None = None, password_hash: str | None = None,
                       public_key: str | None = None) -> Owner:
        """Register an owner/developer with a password (hashed here), a precomputed hash and/or
        an ed25519 public key (base64 raw). An owner with a public key may only publish packages
        signed by that key. "duplicate" if the name is taken."""
        if not isinstance(name, str) or not name.strip() or len(name) > 128:
            raise StoreError(f"invalid owner name {name!r}", ErrorCode.INVALID)
        if password is not None:
            password_hash = hash_password(password)
        if public_key is not None:
            try:
                public_key = public_key_b64(load_public_key(public_key))
            except ValueError as exc:
                raise StoreError(str(exc), ErrorCode.INVALID) from None
        with self._tx() as db:
            if db.execute("SELECT 1 FROM owners WHERE name=?", (name,)).fetchone():
                raise StoreError(f"owner {name!r} already registered", ErrorCode.DUPLICATE)
            db.execute("INSERT INTO owners VALUES (?,?,?,?)", (name, password_hash, public_key, time.time()))
        return Owner(name=name, public_key=public_key, has_password=password_hash is not None)

    def verify_owner(self, name: str, password: str) -> bool:
        """True iff the owner exists and the password matches its stored hash."""
        rows = self._query("SELECT password_hash FROM owners WHERE name=?", (name,))
        return bool(rows) and rows[0][0] is not None and _check_password(password, rows[0][0])

    def bind_owner(self, name: str, jid: str) -> str:
        """The XMPP account that publishes for `name`: bound at its first publish, then fixed.
        Returns the bound JID (compare it with the sender)."""
        with self._tx() as db:
            row = db.execute("SELECT jid FROM owner_jids WHERE owner=?", (name,)).fetchone()
            if row is not None:
                return row[0]
            db.execute("INSERT INTO owner_jids VALUES (?,?)", (name, jid))
            return jid

    def register_robot(self, robot_id: str, robot_type: str, owner: str) -> Robot:
        """Register (or re-register, idempotently) a robot of a known type for a registered owner.
        "forbidden" if the robot id belongs to another owner."""
        if not isinstance(robot_id, str) or not robot_id.strip() or len(robot_id) > 256:
            raise StoreError(f"invalid robot id {robot_id!r}", ErrorCode.INVALID)
        if robot_type not in ROBOT_TYPES:
            raise StoreError(f"unknown robot type {robot_type!r}; known: {sorted(ROBOT_TYPES)}", ErrorCode.INVALID)
        with self._tx() as db:
            if not db.execute("SELECT 1 FROM owners WHERE name=?", (owner,)).fetchone():
                raise StoreError(f"owner {owner!r} is not registered", ErrorCode.NOT_FOUND)
            row = db.execute("SELECT owner FROM robots WHERE robot_id=?", (robot_id,)).fetchone()
            if row and row[0] != owner:
                raise StoreError(f"robot {robot_id!r} is registered to another owner", ErrorCode.FORBIDDEN)
            db.execute("INSERT OR REPLACE INTO robots VALUES (?,?,?,?)",
                       (robot_id, robot_type, owner, time.time()))
        return Robot(robot_id=robot_id, robot_type=robot_type, owner=owner)

    def get_robot(self, robot_id: str) -> Robot:
        """The robot record; "not_found" if unknown."""
        rows = self._query("SELECT robot_id, robot_type, owner FROM robots WHERE robot_id=?", (robot_id,))
        if not rows:
            raise StoreError(f"robot {robot_id!r} is not registered", ErrorCode.NOT_FOUND)
        return Robot(**dict(rows[0]))

    def robots(self, owner: str | None = None) -> list[Robot]:
        """Registered robots, optionally of one owner, sorted by id."""
        sql = "SELECT robot_id, robot_type, owner FROM robots"
        rows = self._query(sql + (" WHERE owner=?" if owner else "") + " ORDER BY robot_id",
                           (owner,) if owner else ())
        return [Robot(**dict(r)) for r in rows]

    # ------------------------------------------------------------------ packages
    def publish(self, owner: str, package_bytes: bytes,
                builds: dict[str, tuple[str, str]] | None = None) -> PackageInfo:
        """Validate and store a package for ``owner``, with its builds: robot type -> (state,
        reason) for each type its manifest declares (default: all "untested", listed at once).

        Refusals: "forbidden" (unknown owner, name owned by someone else, owner has a public key
        and the package is not signed by it), "invalid_package" (any `PackageError`, message kept),
        "duplicate" (this name and version already published). The signer's key is recorded.
        """
        try:
            pkg = read_package(package_bytes, max_size=self.max_package_size,
                               require_signature=self.require_signature)
        except (PackageError, TypeError) as exc:
            raise StoreError(f"invalid package: {exc}", ErrorCode.INVALID_PACKAGE) from None
        m = pkg.manifest
        rows = self._query("SELECT public_key FROM owners WHERE name=?", (owner,))
        if not rows:
            raise StoreError(f"owner {owner!r} is not registered", ErrorCode.FORBIDDEN)
        owner_key = rows[0][0]
        if owner_key is not None and pkg.public_key != owner_key:
            raise StoreError(f"owner {owner!r} must publish packages signed with its registered key", ErrorCode.FORBIDDEN)
        with self._lock:
            self._write_blob(pkg.sha256, bytes(package_bytes))
            try:
                self._insert_version(owner, pkg, builds or {t: ("untested", "") for t in m.robot_types})
            except BaseException:
                self._drop_blob_if_unreferenced(pkg.sha256)
                raise
        return self.info(m.name, m.version)

    def _insert_version(self, owner: str, pkg: Package, builds: dict[str, tuple[str, str]]) -> None:
        m, now = pkg.manifest, time.time()
        with self._tx() as db:
            row = db.execute("SELECT owner FROM packages WHERE name=?", (m.name,)).fetchone()
            if row is None:
                db.execute("INSERT INTO packages VALUES (?,?,?)", (m.name, owner, now))
            elif row[0] != owner:
                raise StoreError(f"package {m.name!r} belongs to another owner", ErrorCode.FORBIDDEN)
            if db.execute("SELECT 1 FROM versions WHERE name=? AND version=?",
                          (m.name, m.version)).fetchone():
                raise StoreError(f"{m.name} {m.version} is already published", ErrorCode.DUPLICATE)
            major, minor, patch = m.version_tuple
            db.execute(
                f"INSERT INTO versions ({_VERSION_COLS}, major, minor, patch) "
                "VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (m.name, m.version, m.description, json.dumps(m.robot_types), json.dumps(m.keywords),
                 json.dumps(m.phrases), m.model_dump_json(), pkg.sha256, pkg.size, pkg.key_id,
                 pkg.public_key, owner, now, 0, major, minor, patch))
            for robot_type in m.robot_types:
                state, reason = builds.get(robot_type, ("untested", ""))
                db.execute("INSERT INTO builds (name, version, robot_type, state, reason) VALUES (?,?,?,?,?)",
                           (m.name, m.version, robot_type, state, reason))

    def _summary(self, row: sqlite3.Row) -> PackageSummary:
        """A version as listed: robot_types are those its builds passed (or had nothing to run)."""
        listed = {r[0] for r in self._query(
            f"SELECT robot_type FROM builds WHERE name=? AND version=? AND state IN {LISTED_STATES}",
            (row["name"], row["version"]))}
        return PackageSummary(name=row["name"], version=row["version"], description=row["description"],
                              robot_types=[t for t in json.loads(row["robot_types"]) if t in listed],
                              keywords=json.loads(row["keywords"]), phrases=json.loads(row["phrases"]),
                              sha256=row["sha256"], size=row["size"])

    def _latest_rows(self, robot_type: str | None = None) -> list[sqlite3.Row]:
        listed = (f"EXISTS (SELECT 1 FROM builds b WHERE b.name=v.name AND b.version=v.version AND "
                  f"b.state IN {LISTED_STATES}")
        where, args = f"WHERE {listed})", ()
        if robot_type is not None:
            where = f"WHERE {listed} AND b.robot_type=?)"
            args = (robot_type,)
        sql = (f"SELECT * FROM (SELECT v.*, ROW_NUMBER() OVER (PARTITION BY name ORDER BY {_ORDER}) AS rn "
               f"FROM versions v {where}) WHERE rn=1 ORDER BY name")
        return self._query(sql, args)

    def list(self, robot_type: str | None = None) -> list[PackageSummary]:
        """Latest listed version of every package, sorted by name. With ``robot_type``: for each
        package, its latest version built for that robot type (packages never built for it are omitted)."""
        if robot_type is not None and robot_type not in ROBOT_TYPES:
            raise StoreError(f"unknown robot type {robot_type!r}; known: {sorted(ROBOT_TYPES)}", ErrorCode.INVALID)
        return [self._summary(r) for r in self._latest_rows(robot_type)]

    def search(self, keyword: str, robot_type: str | None = None) -> list[PackageSummary]:
        """Latest versions whose name, keywords, phrases or description contain ``keyword``
        (case-insensitive). Exact name/keyword matches come first, then by name."""
        needle = (keyword or "").strip().lower()
        if not needle:
            raise StoreError("empty search keyword", ErrorCode.INVALID)
        exact, partial = [], []
        for s in self.list(robot_type):
            if needle == s.name or needle in s.keywords:
                exact.append(s)
            elif any(needle in t.lower() for t in [s.name, s.description, *s.keywords, *s.phrases]):
                partial.append(s)
        return exact + partial

    def vocabulary(self, robot_type: str | None = None) -> dict[str, str]:
        """Isolated-command vocabulary for the Core: keyword -> package name (latest versions;
        on a clash the alphabetically first package wins)."""
        vocab: dict[str, str] = {}
        for s in self.list(robot_type):
            for k in s.keywords:
                vocab.setdefault(k, s.name)
        return vocab

    def _version_row(self, name: str, version: str | None) -> sqlite3.Row:
        if version is None:
            rows = self._query(f"SELECT * FROM versions WHERE name=? ORDER BY {_ORDER} LIMIT 1", (name,))
            if not rows:
                raise StoreError(f"no package named {name!r}", ErrorCode.NOT_FOUND)
        else:
            rows = self._query("SELECT * FROM versions WHERE name=? AND version=?", (name, version))
            if not rows:
                raise StoreError(f"package {name!r} has no version {version!r}", ErrorCode.NOT_FOUND)
        return rows[0]

    def versions(self, name: str) -> list[str]:
        """Published versions of ``name``, newest first; "not_found" if none."""
        rows = self._query(f"SELECT version FROM versions WHERE name=? ORDER BY {_ORDER}", (name,))
        if not rows:
            raise StoreError(f"no package named {name!r}", ErrorCode.NOT_FOUND)
        return [r[0] for r in rows]

    def info(self, name: str, version: str | None = None) -> PackageInfo:
        """Details of one version (latest by default); "not_found" if absent."""
        row = self._version_row(name, version)
        owner = self._query("SELECT owner FROM packages WHERE name=?", (name,))[0][0]
        return PackageInfo(**self._summary(row).model_dump(), owner=owner, manifest=json.loads(row["manifest"]),
                           signer_key_id=row["signer_key_id"], signer_public_key=row["signer_public_key"],
                           published_at=row["published_at"], downloads=row["downloads"],
                           versions=self.versions(name))

    # ------------------------------------------------------------------ builds
    def set_build(self, name: str, version: str, robot_type: str, state: str, reason: str = "",
                  log: str | None = None, started: float | None = None, ended: float | None = None) -> None:
        """A build's new state (its log cut to its last MAX_LOG characters)."""
        sets, args = ["state=?", "reason=?"], [state, reason[:2000]]
        for column, value in (("log", None if log is None else log[-MAX_LOG:]), ("started", started), ("ended", ended)):
            if value is not None:
                sets.append(f"{column}=?")
                args.append(value)
        with self._tx() as db:
            db.execute(f"UPDATE builds SET {', '.join(sets)} WHERE name=? AND version=? AND robot_type=?",
                       (*args, name, version, robot_type))

    def builds(self, name: str | None = None, version: str | None = None) -> list[Build]:
        """Builds kept (of a package, of a version), newest versions first, then by robot type."""
        where, args = [], []
        for column, value in (("b.name", name), ("b.version", version)):
            if value is not None:
                where.append(f"{column}=?")
                args.append(value)
        rows = self._query(
            "SELECT b.name, b.version, b.robot_type, b.state, b.reason, b.started, b.ended, length(b.log) AS log_size "
            "FROM builds b JOIN versions v ON v.name=b.name AND v.version=b.version "
            + (f"WHERE {' AND '.join(where)} " if where else "")
            + "ORDER BY b.name, v.major DESC, v.minor DESC, v.patch DESC, b.robot_type", tuple(args))
        return [Build(**dict(r)) for r in rows]

    def build_log(self, name: str, version: str, robot_type: str) -> str:
        rows = self._query("SELECT log FROM builds WHERE name=? AND version=? AND robot_type=?",
                           (name, version, robot_type))
        if not rows:
            raise StoreError(f"no build of {name} {version} for {robot_type!r}", ErrorCode.NOT_FOUND)
        return rows[0][0]

    def unfinished_builds(self) -> list[Build]:
        """Builds queued, or begun by a Store that stopped before their end (to run again)."""
        return [b for b in self.builds() if b.state in ("queued", "building")]

    def download(self, name: str, version: str | None = None) -> Download:
        """Manifest, archive bytes and sha256 of a version (latest by default); counts the download.
        "not_found" if absent, "corrupt" if the stored blob is missing or damaged."""
        row = self._version_row(name, version)
        sha = row["sha256"]
        try:
            data = self.blob_path(sha).read_bytes()
        except OSError:
            raise StoreError(f"blob of {name} {row['version']} is missing", ErrorCode.CORRUPT) from None
        if sha256_hex(data) != sha:
            raise StoreError(f"blob of {name} {row['version']} is damaged (sha256 mismatch)", ErrorCode.CORRUPT)
        with self._tx() as db:
            db.execute("UPDATE versions SET downloads = downloads + 1 WHERE name=? AND version=?",
                       (name, row["version"]))
        return Download(Manifest.model_validate_json(row["manifest"]), data, sha)

    def delete(self, name: str, version: str | None = None, *, owner: str) -> list[str]:
        """Delete one version (or all with ``version=None``) of a package; only its owner may.
        Returns the deleted versions. Blobs no longer referenced are removed. "not_found" if
        absent, "forbidden" for anyone but the owner."""
        with self._tx() as db:
            row = db.execute("SELECT owner FROM packages WHERE name=?", (name,)).fetchone()
            if row is None:
                raise StoreError(f"no package named {name!r}", ErrorCode.NOT_FOUND)
            if row[0] != owner:
                raise StoreError(f"only the owner of {name!r} may delete it", ErrorCode.FORBIDDEN)
            if version is None:
                rows = db.execute("SELECT version, sha256 FROM versions WHERE name=?", (name,)).fetchall()
            else:
                rows = db.execute("SELECT version, sha256 FROM versions WHERE name=? AND version=?",
                                  (name, version)).fetchall()
                if not rows:
                    raise StoreError(f"package {name!r} has no version {version!r}", ErrorCode.NOT_FOUND)
            for r in rows:
                db.execute("DELETE FROM builds WHERE name=? AND version=?", (name, r[0]))
                db.execute("DELETE FROM versions WHERE name=? AND version=?", (name, r[0]))
            if not db.execute("SELECT 1 FROM versions WHERE name=? LIMIT 1", (name,)).fetchone():
                db.execute("DELETE FROM packages WHERE name=?", (name,))
        for sha in {r[1] for r in rows}:
            self._drop_blob_if_unreferenced(sha)
        return sorted((r[0] for r in rows), key=version_key, reverse=True)


__all__ = ["StoreRepository", "StoreError", "Owner", "Robot", "PackageSummary", "PackageInfo", "Build", "Download",
           "hash_password"]
