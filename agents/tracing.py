"""Message and structure traces: one JSON object per line, appended by every agent of a run.

Agents of several processes (Core, Dynamic, Cloud) append to the same file; each line is written
with one write() on a file opened in append mode, so lines from different processes do not mix.

Record kinds:
  message    dir=send|recv, sender, receiver, performative, conversation_id, ontology, action,
             message_id, in_reply_to, path=direct|xmpp, size, content (capped)
  agent      event=started|stopped|start-failed
  behaviour  event=activated|deactivated, behaviour
  structure  event=register|download|spawn|handoff|cloud-spawn|cloud-destroy|finish|destroy|resume|..
  state      event=enter, fsm, state (FSM states of embodied behaviours)
"""
from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from typing import Any

CONTENT_CAP = 2000  # characters of content kept per message


class TraceWriter:
    def __init__(self, path: str | Path | None):
        self.path = Path(path) if path else None
        self._lock = threading.Lock()
        self._fd: int | None = None
        if self.path:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    @property
    def enabled(self) -> bool:
        return self._fd is not None

    def record(self, kind: str, **fields: Any) -> None:
        if self._fd is None:
            return
        rec = {"t": round(time.time(), 6), "kind": kind, "pid": os.getpid(), **fields}
        line = (json.dumps(rec, default=str, ensure_ascii=False) + "\n").encode()
        with self._lock:
            os.write(self._fd, line)

    def close(self) -> None:
        with self._lock:
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None


_writers: dict[str, TraceWriter] = {}
_writers_lock = threading.Lock()
_NULL = TraceWriter(None)


def tracer_for(path: str | Path | None) -> TraceWriter:
    """One shared writer per file per process; a disabled writer when path is None."""
    if not path:
        return _NULL
    key = str(Path(path).resolve())
    with _writers_lock:
        w = _writers.get(key)
        if w is None or not w.enabled:
            w = _writers[key] = TraceWriter(key)
        return w


def cap(text: str | None, limit: int = CONTENT_CAP) -> str:
    if not text:
        return ""
    return text if len(text) <= limit else text[:limit] + f"...[+{len(text) - limit} chars]"


def read_trace(path: str | Path) -> list[dict]:
    """All records of a trace file in time order; unreadable lines are skipped, not fatal."""
    out = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    out.sort(key=lambda r: r.get("t", 0))
    return out
