"""Message and structure traces: one JSON object per line, appended by every trusted agent of a run.

Trusted agents of several processes (Core, Platform, Store) append to the same file; each line is
written with one write() on a file opened in append mode, so lines from different processes do not
mix. A RApp process (Dynamic, Cloud Agent) holds no descriptor of the file: its records go down a
pipe its Core or Platform reads (`TraceRelay`), which writes each one itself, stamped with the
RApp's identity (`origin`: its JID; `agent` forced to it, what the line claimed kept as
`claimed_agent`; `pid` and `t` its own): a RApp's line can never pass as another agent's, and a
reader tells untrusted records by their `origin`.

The records (their kinds, fields and event names: ontology.trace.RecordKind, StructureEvent...) are
typed in ontology/trace.py. Writing does not validate them (a record is written for every
message); `read_trace(path, validate=True)` does.
"""
from __future__ import annotations

import hashlib
import hmac
import json
import os
import re
import threading
import time
from pathlib import Path
from typing import Any

from ontology.trace import RecordKind, parse_record

CONTENT_CAP = 2000  # characters of content kept per message
# one encoder for every record: json.dumps with options builds a new JSONEncoder per call
_ENCODE = json.JSONEncoder(default=str, ensure_ascii=False).encode
_STR = json.encoder.encode_basestring  # a JSON string (C), as _ENCODE writes it (ensure_ascii off)
_pid = os.getpid()  # a syscall per record otherwise; a forked child resets it


def _after_fork() -> None:
    global _pid
    _pid = os.getpid()


os.register_at_fork(after_in_child=_after_fork)


class TraceWriter:
    def __init__(self, path: str | Path | None, fd: int | None = None):
        self.path = Path(path) if path else None
        self._lock = threading.Lock()
        self._fd: int | None = fd
        # a recording's whole message bodies (record_bodies): the writer of BODIES beside the trace,
        # or this writer itself in a RApp process (raw down its pipe, masked by the relay); None: off
        self.bodies: TraceWriter | None = None
        self.blobs: BlobStore | None = None  # a BODIES writer's store of long strings
        if self.path and fd is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # 0600: a trace holds every message of the run (RApp processes get an append-only fd)
            self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)

    @property
    def enabled(self) -> bool:
        return self._fd is not None

    def record(self, kind: RecordKind | str, **fields: Any) -> None:
        if self._fd is None:
            return
        rec = {"t": round(time.time(), 6), "kind": kind, "pid": _pid, **fields}
        self._write((_ENCODE(rec) + "\n").encode())

    def message(self, direction: str, agent: str, sender: str, receiver: str, performative: str,
                conversation_id: str, ontology: str, action: str, message_id: str, in_reply_to: str,
                path: str, size: int, content: str, feedback: bool = False) -> None:
        """A `message` record (ontology.trace.MessageRecord), written as text: one is written per
        message and side, and building the dict for the JSON encoder cost twice as much
        (bench/messages.py, traced)."""
        if self._fd is None:
            return
        s = _STR
        line = (f'{{"t": {time.time():.6f}, "kind": "message", "pid": {_pid}, '
                + ('"feedback": true, ' if feedback else '')
                + f'"dir": {s(direction)}, "agent": {s(agent)}, "sender": {s(sender)}, '
                f'"receiver": {s(receiver)}, "performative": {s(performative)}, '
                f'"conversation_id": {s(conversation_id)}, "ontology": {s(ontology)}, "action": {s(action)}, '
                f'"message_id": {s(message_id)}, "in_reply_to": {s(in_reply_to)}, "path": {s(path)}, '
                f'"size": {int(size)}, "content": {s(content)}}}\n')
        self._write(line.encode())

    def body(self, direction: str, agent: str, sender: str, receiver: str, performative: str,
             conversation_id: str, ontology: str, action: str, message_id: str, in_reply_to: str,
             body: str, feedback: bool = False) -> None:
        """A message's whole body (ontology.recording.BodyRecord) where a recording is asked for:
        secrets replaced by placeholders (mask_secrets) by a trusted writer, a RApp process's by
        its relay."""
        sink = self.bodies
        if sink is None or (ontology, action) in UNRECORDED_BODIES:
            return
        rec = {"t": round(time.time(), 6), "kind": BODY, "pid": _pid, "dir": direction, "agent": agent,
               "sender": sender, "receiver": receiver, "performative": performative,
               "conversation_id": conversation_id, "ontology": ontology, "action": action,
               "message_id": message_id, "in_reply_to": in_reply_to, "feedback": feedback,
               "body": body}
        if sink is self:  # a RApp process: raw down the pipe, masked by the trusted relay
            self._write((_ENCODE(rec) + "\n").encode())
        else:
            sink.write_body(rec)

    def write_body(self, rec: dict) -> None:
        """A body record into this BODIES writer: secrets masked, long strings of its JSON (camera
        images) kept once as blobs (BlobStore) and named in the body by reference."""
        body = mask_secrets(rec["body"])
        if self.blobs is not None and len(body) >= BLOB_MIN:
            body = self.blobs.extract(body)
        rec["body"] = body
        self._write((_ENCODE(rec) + "\n").encode())

    def _write(self, line: bytes) -> None:
        with self._lock:
            if self._fd is not None:
                os.write(self._fd, line)

    def close(self) -> None:
        with self._lock:
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None


_writers: dict[str, TraceWriter] = {}
_writers_lock = threading.Lock()
_NULL = TraceWriter(None)


_inherited: TraceWriter | None = None


def inherit_trace_fd(fd: int) -> None:
    """A RApp process writes its trace records down the pipe its Core or Platform reads
    (`TraceRelay`): its agents use it where they name no trace file."""
    global _inherited
    _inherited = TraceWriter(None, fd)


def send_bodies_down_pipe() -> None:
    """A RApp process whose run is recorded (SpawnSpec.record): its agents' message bodies go down
    its trace pipe too, for its relay to mask and write."""
    if _inherited is not None:
        _inherited.bodies = _inherited


def record_bodies(trace_path: str | Path) -> TraceWriter:
    """Record the whole body of every message traced to `trace_path` (this process's agents and
    the RApp processes it relays), in BODIES beside it; the RApp packages its Cores run are kept
    in PACKAGES there (keep_package). Returns the trace's writer."""
    writer = tracer_for(trace_path)
    if writer.enabled and writer.bodies is None:
        bodies = TraceWriter(writer.path.parent / BODIES)
        bodies.blobs = BlobStore(writer.path.parent / BLOBS)
        writer.bodies = bodies
    return writer


def stop_recording_bodies(trace_path: str | Path) -> None:
    writer = tracer_for(trace_path)
    bodies, writer.bodies = writer.bodies, None
    if bodies is not None and bodies is not writer:
        bodies.close()


class BlobStore:
    """Long strings of a recording (camera images travel as base64 in several messages and in
    robot.jsonl), each kept once as BLOBS/<sha256> and named where it stood by `<blob:sha256>`."""

    def __init__(self, directory: str | Path):
        self.dir = Path(directory)
        self._known: set[str] = set()
        self._lock = threading.Lock()

    def put(self, text: str) -> str:
        data = text.encode()
        sha = hashlib.sha256(data).hexdigest()
        with self._lock:
            if sha not in self._known:
                self.dir.mkdir(parents=True, exist_ok=True)
                fd = os.open(self.dir / sha, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
                try:
                    os.write(fd, data)
                finally:
                    os.close(fd)
                self._known.add(sha)
        return f"<blob:{sha}>"

    def extract(self, body: str) -> str:
        """The body with each string of BLOB_MIN characters or more in its JSON put in the store."""
        try:
            data = json.loads(body)
        except ValueError:
            return body
        found = [False]

        def walk(v):
            if isinstance(v, str) and len(v) >= BLOB_MIN:
                found[0] = True
                return self.put(v)
            if isinstance(v, dict):
                return {k: walk(x) for k, x in v.items()}
            if isinstance(v, list):
                return [walk(x) for x in v]
            return v
        out = walk(data)
        return json.dumps(out, ensure_ascii=False, separators=(",", ":")) if found[0] else body


def inflate(text: str, blobs_dir: str | Path) -> str:
    """A recorded body (JSON) with its blob references replaced by their strings again."""
    if "<blob:" not in text:
        return text
    d = Path(blobs_dir)
    return _BLOB_REF.sub(lambda m: json.dumps((d / m.group(1)).read_text(), ensure_ascii=False), text)


def blob_store_for(trace_path: str | Path) -> BlobStore | None:
    """The blob store of a recorded trace (None when it is not recorded)."""
    bodies = tracer_for(trace_path).bodies
    return None if bodies is None else bodies.blobs


def keep_package(writer: TraceWriter, data: bytes) -> str | None:
    """A RApp package a Core downloaded, kept beside a recorded trace as PACKAGES/<sha256>.rapp
    (for `rapp replay`); its sha256, or None when the trace is not recorded."""
    if writer.bodies is None or writer.bodies is writer or writer.path is None:
        return None
    sha = hashlib.sha256(data).hexdigest()
    path = writer.path.parent / PACKAGES / f"{sha}.rapp"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{_pid}.part")
        tmp.write_bytes(data)
        tmp.chmod(0o600)
        os.replace(tmp, path)
    return sha


def tracer_for(path: str | Path | None) -> TraceWriter:
    """One shared writer per file per process; the inherited one, or a disabled writer, when
    path is None."""
    if not path:
        return _inherited or _NULL
    key = str(Path(path).resolve())
    with _writers_lock:
        w = _writers.get(key)
        if w is None or not w.enabled:
            w = _writers[key] = TraceWriter(key)
        return w


class TraceRelay:
    """The trusted end of a RApp process's trace pipe: each line read becomes a record written by
    `writer` (the Core's or Platform's), stamped with `who()` (the RApp's JID now: a warm worker
    takes its run's at the hand-off) and `pid()`. What cannot be a record is kept as a `log` record
    saying so; a line over MAX_LINE is cut; past MAX_BYTES a run's records are dropped, once said."""

    MAX_LINE = 2 * 1024**2  # a message body (agents/base.py MAX_BODY, 256 K characters) escaped
    MAX_BYTES = 64 * 1024**2
    MAX_BODY_BYTES = 512 * 1024**2  # of a recording's message bodies (camera images)

    def __init__(self, fd: int, writer: TraceWriter, who, pid):
        self.fd, self.writer, self.who, self.pid = fd, writer, who, pid
        self._buf = b""
        self._bytes = self._body_bytes = 0
        self._loop = None

    def start(self, loop) -> None:
        os.set_blocking(self.fd, False)
        self._loop = loop
        loop.add_reader(self.fd, self._readable)

    def _readable(self) -> None:
        try:
            data = os.read(self.fd, 262144)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self.close()
            return
        self._buf += data
        *lines, self._buf = self._buf.split(b"\n")
        if len(self._buf) > self.MAX_LINE:
            lines.append(self._buf[:self.MAX_LINE])
            self._buf = b""
        for line in lines:
            if line.strip():
                self._one(line[:self.MAX_LINE])

    def close(self) -> None:
        if self._loop is None:
            return
        self._loop.remove_reader(self.fd)
        self._loop = None
        if self._buf.strip():
            self._one(self._buf[:self.MAX_LINE])
        self._buf = b""
        os.close(self.fd)

    def _one(self, line: bytes) -> None:
        if _BODY_KIND in line[:80]:
            self._body(line)
            return
        self._bytes += len(line)
        if self._bytes > self.MAX_BYTES:
            if self._bytes - len(line) <= self.MAX_BYTES:
                self.writer.record(RecordKind.LOG, agent=self.who(), origin=self.who(), level="WARNING",
                                   message=f"trace records past {self.MAX_BYTES} bytes dropped")
            return
        try:
            rec = json.loads(line)
        except ValueError:
            rec = None
        if not isinstance(rec, dict):
            rec = {"kind": RecordKind.LOG, "level": "WARNING",
                   "message": "not a trace record: " + line[:300].decode(errors="replace")}
        who = self.who()
        if rec.get("agent") not in (None, who):
            rec["claimed_agent"] = rec["agent"]
        rec.pop("origin", None)
        rec.update(t=round(time.time(), 6), pid=self.pid(), agent=who, origin=who)
        try:
            self.writer._write((_ENCODE(rec) + "\n").encode())  # noqa: SLF001 - one line, one write
        except (TypeError, ValueError, OSError):
            pass


    def _body(self, line: bytes) -> None:
        """A RApp's message body (TraceWriter.body): masked here, written to the recording's
        BODIES with the RApp's identity, or dropped when its run is not recorded."""
        sink = self.writer.bodies
        if sink is None or sink is self.writer:
            return
        self._body_bytes += len(line)
        if self._body_bytes > self.MAX_BODY_BYTES:
            if self._body_bytes - len(line) <= self.MAX_BODY_BYTES:
                self.writer.record(RecordKind.LOG, agent=self.who(), origin=self.who(), level="WARNING",
                                   message=f"message bodies past {self.MAX_BODY_BYTES} bytes not recorded")
            return
        try:
            rec = json.loads(line)
            body = rec["body"]
            if not isinstance(body, str):
                raise ValueError
        except (ValueError, KeyError, TypeError):
            return
        who = self.who()
        if rec.get("agent") not in (None, who):
            rec["claimed_agent"] = rec["agent"]
        rec.pop("origin", None)
        rec.update(t=round(time.time(), 6), pid=self.pid(), agent=who, origin=who, body=body)
        try:
            sink.write_body(rec)
        except (TypeError, ValueError, OSError):
            pass


_SECRET = re.compile(r'("(?:password|token)"\s*:\s*")[^"]*(")')
BODY = "body"  # the kind of a recording's body record (ontology/recording.py BodyRecord)
BODIES = "messages.jsonl"  # a recording's message bodies, beside its trace
PACKAGES = "packages"  # a recording's RApp packages, beside its trace
BLOBS = "blobs"  # a recording's long strings (BlobStore), beside its trace
# whole in the trace already, numerous, and no replay needs them (four a second for a whole run)
UNRECORDED_BODIES = frozenset({("core", "heartbeat")})
BLOB_MIN = 4096  # characters of a string kept as a blob
_BLOB_REF = re.compile(r'"<blob:([0-9a-f]{64})>"')
SECRET_FIELDS = frozenset({"password", "token"})
_BODY_KIND = b'"kind": "body"'  # near the start of a body line (TraceWriter.body), after "t"
_KEY = os.urandom(32)  # this process's: placeholders are stable within it, and say nothing of the secret
_SECRET_VALUE = re.compile(r'("(?:password|token)"\s*:\s*")((?:[^"\\]|\\.)*)(")')


def placeholder(secret: str) -> str:
    """What a recording writes instead of a secret: the same for the same secret in one process
    (a keyed hash, the key never written), so a replay can substitute its own values consistently."""
    return "<secret:" + hmac.new(_KEY, secret.encode(), hashlib.sha256).hexdigest()[:16] + ">"


def is_placeholder(value) -> bool:
    return isinstance(value, str) and value.startswith("<secret:") and value.endswith(">") and len(value) == 25


def mask_secrets(body: str) -> str:
    """A message body with the value of every `password` and `token` field (at any depth of its
    JSON) replaced by its placeholder; a body that is not JSON has such fields replaced as text."""
    if not body or ('"password"' not in body and '"token"' not in body):
        return body
    try:
        data = json.loads(body)
    except ValueError:
        return _SECRET_VALUE.sub(lambda m: m.group(1) + placeholder(m.group(2)) + m.group(3), body)
    return json.dumps(_masked(data), ensure_ascii=False, separators=(",", ":"))


def _masked(value):
    if isinstance(value, dict):
        return {k: (placeholder(v) if k in SECRET_FIELDS and isinstance(v, str) and v else _masked(v))
                for k, v in value.items()}
    if isinstance(value, list):
        return [_masked(v) for v in value]
    return value


def cap(text: str | None, limit: int = CONTENT_CAP) -> str:
    """Message content as traced: secrets (password and token fields) masked, then capped."""
    if not text:
        return ""
    text = _SECRET.sub(r"\1***\2", text) if ("password" in text or "token" in text) else text
    return text if len(text) <= limit else text[:limit] + f"...[+{len(text) - limit} chars]"


def read_trace(path: str | Path, validate: bool = False) -> list[dict]:
    """All records of a trace file in time order; unreadable lines are skipped, not fatal, and so
    are, with `validate`, records that are not an ontology.trace.TraceRecord."""
    out = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            try:
                rec = json.loads(line)
                if validate:
                    parse_record(rec)
            except ValueError:  # json.JSONDecodeError and pydantic.ValidationError are ValueErrors
                continue
            out.append(rec)
    out.sort(key=lambda r: r.get("t", 0))
    return out
