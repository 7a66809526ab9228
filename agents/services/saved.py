"""What the Platform keeps of each user across its restart: homes, maps, learned objects, faces and
scenes, cognitive history, obstacle marks, speech noise profiles (paper 000 sec. 6.3: "each user has a
personal set of face images to be recognised, maps for navigation etc.").

`SavedData(folder)`: SQLite `services.db` (WAL) holds one row per (kind, user, key) with its metadata
as JSON; binary content (a map's PNG, feature arrays) lives in content-addressed blob files
`blobs/<sha256[:2]>/<sha256>`, written (and synced) before the row that names them, so a crash
leaves at worst an unreferenced blob, swept at the next start. A blob found missing or damaged
drops that one record (logged), never the rest. The folder is 0700, the files 0600. Methods are
synchronous and thread-safe; the services call them from their worker threads, never from the event
loop. The stores (HomeStore, MapStore, ObjectModels, ...) load their rows when created and write
through on every change; `ServiceState.keeping(folder)` makes a state that keeps its stores here.
"""
from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import threading
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from ..schema import open_migrated


log = logging.getLogger("rapp.platform")

# schema versions (agents/schema.py)
MIGRATIONS: tuple = ("""
CREATE TABLE IF NOT EXISTS records (
    kind TEXT NOT NULL,
    user TEXT NOT NULL,
    key TEXT NOT NULL,
    meta TEXT NOT NULL,
    blob TEXT,
    updated REAL NOT NULL,
    PRIMARY KEY (kind, user, key)
);
CREATE INDEX IF NOT EXISTS records_blob ON records(blob)
""",)


class Record(NamedTuple):
    user: str
    key: str
    meta: Any
    blob: bytes | None


def _private_dir(path: Path) -> None:
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    os.chmod(path, 0o700)


class SavedData:
    """Per-user records of the Platform's services in `folder` (created, 0700)."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        _private_dir(self.folder)
        self.blob_dir = self.folder / "blobs"
        _private_dir(self.blob_dir)
        path = self.folder / "services.db"
        self._lock = threading.RLock()
        # synchronous=NORMAL: a commit survives the process killed; a power cut may lose the last
        self._db = open_migrated(path, MIGRATIONS, f"the Platform's services database {path}",
                                 pragmas=("synchronous=NORMAL",))
        self.sweep()

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # ------------------------------------------------------------------ blobs
    def _blob_path(self, digest: str) -> Path:
        return self.blob_dir / digest[:2] / digest

    def _write_blob(self, data: bytes) -> str:
        digest = hashlib.sha256(data).hexdigest()
        path = self._blob_path(digest)
        if not path.exists():
            _private_dir(path.parent)
            tmp = path.with_name(f".{digest}.{os.getpid()}.{threading.get_ident()}")
            with os.fdopen(os.open(tmp, os.O_CREAT | os.O_WRONLY | os.O_TRUNC, 0o600), "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        return digest

    def _read_blob(self, digest: str) -> bytes | None:
        try:
            data = self._blob_path(digest).read_bytes()
        except OSError:
            return None
        return data if hashlib.sha256(data).hexdigest() == digest else None

    def _drop_blobs(self, digests) -> None:
        """Delete blob files no row names any more (call with the lock held, after the commit)."""
        for digest in {d for d in digests if d}:
            if not self._db.execute("SELECT 1 FROM records WHERE blob=? LIMIT 1", (digest,)).fetchone():
                self._blob_path(digest).unlink(missing_ok=True)

    def sweep(self) -> int:
        """Delete blob files no row names (a crash between a blob's write and its row's commit)."""
        with self._lock:
            named = {d for (d,) in self._db.execute("SELECT DISTINCT blob FROM records WHERE blob IS NOT NULL")}
            gone = 0
            for path in self.blob_dir.glob("*/*"):
                if path.name not in named:
                    path.unlink(missing_ok=True)
                    gone += 1
            return gone

    # ------------------------------------------------------------------ records
    def put(self, kind: str, user: str, key: str, meta: Any, blob: bytes | None = None) -> None:
        """Keep (replace) one record; `meta` is anything JSON can hold."""
        text = json.dumps(meta, separators=(",", ":"))
        with self._lock:
            digest = self._write_blob(blob) if blob is not None else None
            old = self._db.execute("SELECT blob FROM records WHERE kind=? AND user=? AND key=?",
                                   (kind, user, key)).fetchone()
            self._db.execute("INSERT OR REPLACE INTO records VALUES (?,?,?,?,?,?)",
                             (kind, user, key, text, digest, time.time()))
            if old and old[0] != digest:
                self._drop_blobs([old[0]])

    def delete(self, kind: str, user: str, key: str | None = None) -> int:
        """Forget one record, or all of a user's of that kind (key None); how many."""
        where, args = ("kind=? AND user=?", (kind, user)) if key is None else \
            ("kind=? AND user=? AND key=?", (kind, user, key))
        with self._lock:
            blobs = [d for (d,) in self._db.execute(f"SELECT blob FROM records WHERE {where}", args)]
            count = self._db.execute(f"DELETE FROM records WHERE {where}", args).rowcount
            self._drop_blobs(blobs)
            return count

    def records(self, kind: str) -> list[Record]:
        """Every record of a kind, oldest change first; one whose blob is missing or damaged is left out
        (and logged), as is one whose metadata does not parse."""
        with self._lock:
            rows = self._db.execute("SELECT user, key, meta, blob FROM records WHERE kind=? ORDER BY updated",
                                    (kind,)).fetchall()
            out = []
            for user, key, meta, digest in rows:
                blob = None
                if digest is not None:
                    blob = self._read_blob(digest)
                    if blob is None:
                        log.warning("saved %s %r of %s: its blob %s is missing or damaged; left out",
                                    kind, key, user, digest[:12])
                        continue
                try:
                    out.append(Record(user, key, json.loads(meta), blob))
                except ValueError:
                    log.warning("saved %s %r of %s: unreadable metadata; left out", kind, key, user)
            return out


# ------------------------------------------------------------------ array helpers
def pack_arrays(**arrays: np.ndarray) -> bytes:
    """Arrays as one .npz blob (no pickles: a saved file is data, never code)."""
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def unpack_arrays(blob: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(blob), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


class SavedArrays(dict):
    """A {(user, name): array} store that writes each entry through to `saved` (kind `kind`): the
    speech noise profiles (agents/services/speech.py sets items; the service pool merges with update)."""

    def __init__(self, saved: SavedData, kind: str) -> None:
        super().__init__()
        self.saved, self.kind = saved, kind
        for rec in saved.records(kind):
            super().__setitem__((rec.user, rec.key), unpack_arrays(rec.blob)["value"])

    def __setitem__(self, key, value) -> None:
        user, name = key
        self.saved.put(self.kind, user, name, {}, pack_arrays(value=np.asarray(value)))
        super().__setitem__(key, value)

    def update(self, *args, **kw) -> None:
        for key, value in dict(*args, **kw).items():
            self[key] = value


def keep_obstacles(layers, saved: SavedData) -> None:
    """Keep an ObstacleLayers' marks in `saved` (kind "obstacles", one record per user and map) and put
    back those kept: each mark's expiry is kept as wall-clock time, so time spent stopped counts."""
    for rec in saved.records("obstacles"):
        now = time.time()
        layers.restore(rec.user, rec.key, [(k["id"], k["x"], k["y"], k["radius_m"], k["expires_at"] - now,
                                            k.get("note", "")) for k in rec.meta["marks"]], rec.meta["next_id"])

    def changed(user: str, map_id: str, marks, next_id: int) -> None:
        now = time.time()
        saved.put("obstacles", user, map_id, {"next_id": next_id, "marks": [
            {"id": k.id, "x": k.x, "y": k.y, "radius_m": k.radius_m, "note": k.note,
             "expires_at": now + layers.expires_in(k)} for k in marks]})

    layers.on_change = changed
