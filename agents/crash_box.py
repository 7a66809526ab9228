"""The last request a Cloud Agent's process took, kept where a crash cannot take it.

A Cloud Agent crashed in native code in a fleet run (OpenCV, a segmentation fault in the middle of
`observe`): the faulthandler's stack said where, but the frame that did it was gone. Now the process
copies each request's body into a file it has mapped (a memory copy, ~0.2 ms for a 2 MB frame); the
kernel keeps those pages however the process dies. The Platform reads the file only when the process
ended unasked, and keeps a copy next to its record of the loss (`cloud-lost`, `input`).

Layout: 8 bytes of length (little-endian), then `action`, a newline, the body (UTF-8). The length is
written last, so a crash in the middle of a copy leaves no half request. The file is the RApp's to
write too: it is read as untrusted (bounded, decoded with replacement)."""
from __future__ import annotations

import json
import mmap
import os
import struct
from pathlib import Path

from .sandbox import open_run_file

BOX_NAME = "request-in-progress.box"
_HEADER = struct.Struct("<Q")
MAX_KEPT = 4 * 1024 * 1024  # bytes read back at most (a request body is far smaller: agents/base.py MAX_BODY)


class CrashBox:
    def __init__(self, path: str | Path, size: int = 64 * 1024):
        self.path = Path(path)
        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600)
        self._map: mmap.mmap | None = None
        self._grow(size)

    def _grow(self, size: int) -> None:
        if self._map is not None:
            self._map.close()
        os.ftruncate(self._fd, size)
        self._map = mmap.mmap(self._fd, size)

    def hold(self, action: str, body: str) -> None:
        """Keep this request in place of the one before."""
        data = action.encode() + b"\n" + body.encode()
        need = _HEADER.size + len(data)
        if need > len(self._map):
            self._grow(max(need, 2 * len(self._map)))
        self._map[:_HEADER.size] = _HEADER.pack(0)
        self._map[_HEADER.size:need] = data
        self._map[:_HEADER.size] = _HEADER.pack(len(data))

    def close(self) -> None:
        if self._map is not None:
            self._map.close()
            self._map = None
        os.close(self._fd)


def read_box(path: str | Path) -> tuple[str, str] | None:
    """(action, body) of the request a box holds, or None (no box, or no complete request)."""
    try:
        with open_run_file(Path(path), "rb") as f:  # the RApp's own directory
            head = f.read(_HEADER.size)
            if len(head) < _HEADER.size:
                return None
            (n,) = _HEADER.unpack(head)
            if n == 0 or n > MAX_KEPT:
                return None
            data = f.read(n)
    except OSError:
        return None
    action, _, body = data.decode(errors="replace").partition("\n")
    return action, body


def keep_crash_input(box: str | Path, dest: str | Path) -> Path | None:
    """Copy a crashed process's last request out of its run directory (which goes with its
    clean-up) to `dest`, as JSON; None when there was none."""
    held = read_box(box)
    if held is None:
        return None
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps({"action": held[0], "body": held[1]}))
    return dest
