"""Run a command as an unprivileged user (uid/gid 65534), as a developer without root would.

    python tests/sandbox/as_nobody.py PATH[:PATH...] COMMAND...

Root only. In a mount namespace of its own, every directory on the way to each PATH that others may
not enter (a Python installed under /root, 0700) is covered by a tmpfs in which only the way to PATH
is bound again: the command sees the interpreter and the project as a developer's laptop would, and
nothing else of those directories. The machine's own mounts and files are not changed.
"""
import ctypes
import os
import sys

MS_BIND, MS_REC, MS_PRIVATE, MS_MOVE = 0x1000, 0x4000, 0x40000, 0x2000
NOBODY = 65534


def _closed_ancestor(path: str) -> tuple[str | None, str | None]:
    """The first directory on the way to `path` others may not enter, and the next name under it."""
    parts = path.strip("/").split("/")
    for i in range(1, len(parts)):
        d = "/" + "/".join(parts[:i])
        if not os.stat(d).st_mode & 0o001:
            return d, parts[i]
    return None, None


def main() -> None:
    lib = ctypes.CDLL(None, use_errno=True)

    def check(ret: int, what: str) -> None:
        if ret != 0:
            raise OSError(ctypes.get_errno(), what)

    check(lib.unshare(0x20000), "unshare(mount namespace)")
    check(lib.mount(b"none", b"/", None, MS_REC | MS_PRIVATE, None), "private mounts")
    spare = f"/run/as-nobody-{os.getpid()}"
    os.makedirs(spare, exist_ok=True)
    for path in sys.argv[1].split(":"):
        while True:
            closed, child = _closed_ancestor(os.path.realpath(path))
            if closed is None:
                break
            check(lib.mount(f"{closed}/{child}".encode(), spare.encode(), None, MS_BIND | MS_REC, None), "bind")
            check(lib.mount(b"tmpfs", closed.encode(), b"tmpfs", 0, b"mode=0755"), "tmpfs")
            os.makedirs(f"{closed}/{child}")
            check(lib.mount(spare.encode(), f"{closed}/{child}".encode(), None, MS_MOVE, None), "move")
    os.setgroups([])
    os.setresgid(NOBODY, NOBODY, NOBODY)
    os.setresuid(NOBODY, NOBODY, NOBODY)
    os.execv(sys.argv[2], sys.argv[2:])


if __name__ == "__main__":
    main()
