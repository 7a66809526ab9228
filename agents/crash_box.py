"""The requests a Cloud Agent's process is working on, kept where a crash cannot take them.

A Cloud Agent crashed in native code in a fleet run (OpenCV, a segmentation fault in the middle of
`observe`): the faulthandler's stack said where, but the frame that did it was gone. Now the process
copies each request's body into a file it has mapped when it takes the request (a memory copy,
~0.2 ms for a 2 MB frame), and marks it done when the answer is made; the kernel keeps those
pages however the process dies. So the box holds every request in progress (a RApp may have several
running at once: the last one taken need not be the one that crashed) and, once it is done, the
last one taken (a crash between requests, in a thread of the RApp's own, may still be about it).
The Platform reads the file only when the process ended unasked, and keeps a copy next to its
record of the loss (`cloud-lost`, `input`).

Layout: 8 bytes of length (little-endian), then one record per request, oldest first: 4 bytes of
length, 1 byte (1: in progress, 0: done), `action`, a newline, the body (UTF-8). The length is
written last, so a crash in the middle of a copy leaves an empty box, never half a request. The
file is the RApp's to write too: it is read as untrusted (bounded, decoded with replacement)."""
from __future__ import annotations

import itertools
import json
import mmap
import os
import struct
from pathlib import Path

from .sandbox import open_run_file

BOX_NAME = "request-in-progress.box"
_HEADER = struct.Struct("<Q")
_RECORD = struct.Struct("<IB")  # length, in progress
MAX_KEPT = 4 * 1024 * 1024  # bytes read back at most (a request body is far smaller: agents/base.py MAX_BODY)


class CrashBox:
    def __init__(self, path: str | Path, size: int = 64 * 1024):
        self.path = Path(path)
        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600)
        self._map: mmap.mmap | None = None
        self._held: dict[int, bytes] = {}  # ticket -> request in progress, in the order taken
        self._last: tuple[int, bytes] | None = None  # the last request taken: (ticket, request)
        self._tickets = itertools.count(1)
        self._grow(size)

    def _grow(self, size: int) -> None:
        if self._map is not None:
            self._map.close()
        os.ftruncate(self._fd, size)
        self._map = mmap.mmap(self._fd, size)

    def hold(self, action: str, body: str) -> int:
        """Keep this request with the others in progress; the ticket releases it."""
        ticket = next(self._tickets)
        self._held[ticket] = action.encode() + b"\n" + body.encode()
        self._last = (ticket, self._held[ticket])
        self._write()
        return ticket

    def release(self, ticket: int) -> None:
        """The request's answer is made: it is no longer in progress."""
        if self._held.pop(ticket, None) is not None:
            self._write()

    def _write(self) -> None:
        records = [(1, d) for d in self._held.values()]
        if self._last is not None and self._last[0] not in self._held:
            records.append((0, self._last[1]))
        need = _HEADER.size + sum(_RECORD.size + len(d) for _, d in records)
        if need > len(self._map):
            self._grow(max(need, 2 * len(self._map)))
        self._map[:_HEADER.size] = _HEADER.pack(0)
        at = _HEADER.size
        for flag, d in records:  # straight into the map: a 2 MB frame is copied once
            self._map[at:at + _RECORD.size] = _RECORD.pack(len(d), flag)
            self._map[at + _RECORD.size:at + _RECORD.size + len(d)] = d
            at += _RECORD.size + len(d)
        self._map[:_HEADER.size] = _HEADER.pack(need - _HEADER.size)

    def close(self) -> None:
        if self._map is not None:
            self._map.close()
            self._map = None
        os.close(self._fd)


def read_box(path: str | Path) -> list[tuple[str, str, bool]] | None:
    """(action, body, in progress) of each request a box holds, oldest first; None when there is no
    box (or it is not one)."""
    try:
        with open_run_file(Path(path), "rb") as f:  # the RApp's own directory
            head = f.read(_HEADER.size)
            if len(head) < _HEADER.size:
                return None
            (n,) = _HEADER.unpack(head)
            if n > MAX_KEPT:
                return None
            data = f.read(n)
    except OSError:
        return None
    out, at = [], 0
    while at + _RECORD.size <= len(data):
        size, flag = _RECORD.unpack_from(data, at)
        record = data[at + _RECORD.size:at + _RECORD.size + size]
        if len(record) < size:
            break  # a record that lies about its length ends the list
        action, _, body = record.decode(errors="replace").partition("\n")
        out.append((action, body, bool(flag)))
        at += _RECORD.size + size
    return out


def keep_crash_input(box: str | Path, dest: str | Path) -> Path | None:
    """Copy the requests a crashed process held out of its run directory (which goes with its
    clean-up) to `dest`, as JSON ({"requests": [{action, body, in_progress}], oldest first}); None
    when it had taken none."""
    held = read_box(box)
    if not held:
        return None
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps({"requests": [{"action": a, "body": b, "in_progress": p} for a, b, p in held]}))
    return dest
