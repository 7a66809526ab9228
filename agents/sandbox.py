"""The sandbox a RApp process (Dynamic or Cloud Agent) runs in: defence in depth around untrusted code.

Layers, each applied by the runtime to its own process first thing, before it reads its spec or
imports anything of a RApp (`confine`, from what `Sandbox.confinement` put in its environment), in
this order:
1. rlimits (agents/process.py `Limits`): CPU, address space, processes, open files, file size;
2. a private mount namespace whose root is a fresh tmpfs holding only read-only binds of the
   system (/usr, /etc, the shared-library symlinks), the Python installation and virtualenv, the
   project's own packages, a minimal /dev (null, zero, random, urandom) and the run's directory
   (read-write, as /app); nothing else of the machine is there: no /proc (so no parent's environ),
   no /tmp, no /root, no data directory of any agent, no credentials file;
3. a user id of its own (one per run, never an account of the machine): the RApp cannot read what
   its own uid does not own, signal other processes, undo the mounts, or get privileges back
   (no_new_privs); rlimits on processes count this run's processes only.

This needs root (CAP_SYS_ADMIN, CAP_SETUID), as a robot's Core service has. Without it the
sandbox is "off": rlimits and the scrubbed environment only, which a deployment must not accept
(`rapp agent core` refuses unless --allow-unsandboxed). Network: the process shares the host's
network; a deployment restricts the sandbox uids to the XMPP server with a firewall rule
(docs/deployment.md), since a private network namespace would cut the XMPP connection too.
"""
from __future__ import annotations

import ctypes
import dataclasses
import functools
import json
import os
import secrets
import signal
import stat
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from xmpp_server.process import PR_SET_PDEATHSIG, libc

UID_BASE = 0x5AF0_0000  # sandbox uids: UID_BASE .. UID_BASE + 2**20, no account of the machine
APP_DIR = "/app"
DEVICES = ("null", "zero", "random", "urandom")
SYSTEM = ("/usr", "/etc")
PROJECT_PACKAGES = ("agents", "behaviours", "ontology", "robots", "rapps", "xmpp_server")
ENV_ALLOWED = ("PATH", "LANG", "LC_ALL", "LC_CTYPE", "TZ")

_CLONE_NEWNS = 0x00020000
_MS_RDONLY, _MS_NOSUID, _MS_NODEV, _MS_REMOUNT = 0x1, 0x2, 0x4, 0x20
_MS_BIND, _MS_REC, _MS_PRIVATE = 0x1000, 0x4000, 0x40000
_PR_SET_NO_NEW_PRIVS = 38


class SandboxError(RuntimeError):
    pass


@functools.lru_cache(maxsize=1)
def available() -> bool:
    """Can this process build the sandbox? Root on Linux, and a mount namespace can really be made
    (a root without CAP_SYS_ADMIN, as in an unprivileged container, cannot): tried once, in a
    throwaway child."""
    if not (sys.platform.startswith("linux") and os.geteuid() == 0 and libc() is not None):
        return False
    probe = ("import ctypes, ctypes.util, sys; libc = ctypes.CDLL(ctypes.util.find_library('c')); "
             f"sys.exit(0 if libc.unshare({_CLONE_NEWNS}) == 0 else 1)")
    try:
        return subprocess.run([sys.executable, "-c", probe], timeout=20, capture_output=True).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def _check(ret: int, what: str) -> None:
    if ret != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"{what}: {os.strerror(err)}")


def _project_root() -> Path:
    return Path(__file__).resolve().parent.parent


def _python_dirs() -> list[str]:
    """The interpreter's installation and the virtualenv, as real paths (a venv's python is a
    symlink into the base installation; both paths must resolve inside the sandbox)."""
    dirs = {os.path.realpath(sys.base_prefix), os.path.realpath(sys.prefix), sys.prefix,
            os.path.dirname(os.path.realpath(sys.executable))}
    out: list[str] = []
    for d in sorted(dirs, key=len):  # a directory inside one already bound needs no bind
        if not any(d == o or d.startswith(o + "/") for o in out) and os.path.isdir(d):
            out.append(d)
    return out


@dataclass
class Sandbox:
    """How RApp processes are confined: `enabled=False` keeps only rlimits and the scrubbed
    environment (development machines without root)."""

    enabled: bool = field(default_factory=available)
    tmpfs_mb: int = 256  # /app/tmp and the sandbox root live in RAM: capped

    def env(self, settings, extra: dict[str, str] | None = None) -> dict[str, str]:
        """The child's whole environment: an allow-list, never a copy of the parent's."""
        env = {k: os.environ[k] for k in ENV_ALLOWED if k in os.environ}
        env.setdefault("PATH", "/usr/local/bin:/usr/bin:/bin")
        home = APP_DIR if self.enabled else None
        env.update(PYTHONPATH=str(_project_root()), PYTHONDONTWRITEBYTECODE="1", PYTHONNOUSERSITE="1")
        if home:
            env.update(HOME=home, TMPDIR=f"{home}/tmp", MPLCONFIGDIR=f"{home}/tmp")
        env.update(settings.to_env(fields=("host", "port", "fallback", "domain", "auto_register",
                                            "verify_tls", "force_xmpp", "start_timeout")))
        env.update(extra or {})
        return env

    def new_uid(self) -> int | None:
        return UID_BASE + secrets.randbelow(1 << 20) if self.enabled else None

    def prepare(self, workdir: Path, uid: int | None) -> None:
        """Give the run's directory to its uid (0700): no other run can read it."""
        workdir.mkdir(parents=True, exist_ok=True)
        (workdir / "tmp").mkdir(exist_ok=True)
        if uid is None:
            return
        give_tree(workdir, uid)
        os.chmod(workdir, 0o700)
        root = workdir / ".root"  # mount point of the sandbox's root
        if root.is_symlink() or (root.exists() and not root.is_dir()):
            root.unlink()  # left by the run's last process (a Cloud Agent restarts in its directory)
        root.mkdir(exist_ok=True)
        os.lchown(root, 0, 0)

    def confinement(self, uid: int | None, limits, nice: int = 0) -> str:
        """What a RApp process applies to itself at its start (`confine`), for its environment
        (CONFINE_ENV). Not a `preexec_fn`: with one, CPython cannot vfork, and the fork of a large
        Core or Platform (50 ms for a Platform's 220 MB) holds the GIL, and the logging modules'
        at-fork locks, all along: the parent's event loop stood still for each spawn."""
        return json.dumps({"uid": uid, "tmpfs_mb": self.tmpfs_mb, "nice": nice,
                           "binds": self._binds() if uid is not None else [],
                           "limits": dataclasses.asdict(limits), "parent": os.getpid()})

    def _binds(self) -> list[tuple[str, str, bool]]:
        """(source, target inside the sandbox, writable) for every bind of the sandbox's root."""
        root = _project_root()
        out = [(p, p, False) for p in SYSTEM if os.path.isdir(p)]
        out += [(p, p, False) for p in _python_dirs() if not any(p.startswith(s + "/") for s in SYSTEM)]
        out += [(str(root / pkg), str(root / pkg), False) for pkg in PROJECT_PACKAGES if (root / pkg).is_dir()]
        out += [(f"/dev/{d}", f"/dev/{d}", True) for d in DEVICES if os.path.exists(f"/dev/{d}")]
        return out  # and the run's directory as /app: the process's cwd (`confine`)


def open_run_file(path: Path, mode: str):
    """A file of a run directory, opened by the Core or Platform (root): a regular file, no link
    followed. The directory is the run's uid's, and a Cloud Agent restarts in it: its last process
    could have left a log as a link to a file of root's (appended to, or quoted in a record), or a
    FIFO (O_NONBLOCK: refused at once instead of blocking the open). `mode`: "rb" or "ab"."""
    flags = os.O_NOFOLLOW | os.O_NONBLOCK | (os.O_WRONLY | os.O_APPEND | os.O_CREAT if "a" in mode else os.O_RDONLY)
    fd = os.open(path, flags, 0o644)
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise OSError(f"{path} is not a regular file")
    return os.fdopen(fd, mode)


def give_tree(top: Path, uid: int) -> None:
    """Everything under `top` (itself included) to `uid`, walking by directory descriptors with no
    link followed: a run directory reused (a Cloud Agent's restart) is its last uid's, and a path
    walked by name could be redirected through a directory swapped for a link meanwhile."""
    os.chown(top, uid, uid, follow_symlinks=False)
    for _, dirs, files, dirfd in os.fwalk(top):
        for name in dirs + files:
            os.chown(name, uid, uid, dir_fd=dirfd, follow_symlinks=False)


CONFINE_ENV = "RAPP_CONFINE"


def confine() -> None:
    """Confine this process as its Core or Platform asked (CONFINE_ENV; nothing asked, nothing
    done): rlimits, then (a sandbox uid) the mount namespace and its root, the uid, no_new_privs;
    then the parent-death signal (the uid change clears it) and the priority. As root, before any
    RApp code: the runtime calls it first thing. Any failure ends the process (126), with the reason
    in its stderr.log: it never goes on unconfined."""
    raw = os.environ.pop(CONFINE_ENV, None)
    if raw is None:
        return
    try:
        from .process import Limits
        from .priority import set_group_nice

        asked = json.loads(raw)
        uid, lib = asked["uid"], libc()
        if asked["nice"]:  # its session's group, while root (no rate limit); its threads' below
            set_group_nice(os.getpid(), os.getpriority(os.PRIO_PROCESS, 0) + asked["nice"])
        Limits(**asked["limits"]).apply(own_uid=uid is not None)
        if uid is not None:
            # the run's directory as the cwd Popen gave (relative paths), not by its name: a warm
            # worker's directory is renamed at its hand-off, which may come before it got this far
            _enter(lib, Path(".root"), [*asked["binds"], (".", APP_DIR, True)], asked["tmpfs_mb"])
            os.setgroups([])
            os.setresgid(uid, uid, uid)
            os.setresuid(uid, uid, uid)
            _check(lib.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0), "no_new_privs")
        if lib is not None:  # after the uid change, which clears it: dies with its Core/Platform
            _check(lib.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0), "parent-death signal")
            if os.getppid() != asked["parent"]:
                os._exit(125)  # the parent died before the signal was armed
        if asked["nice"]:
            os.nice(asked["nice"])  # lowering needs no privilege; after the uid change: the run's own
    except BaseException as e:  # noqa: BLE001 - say why in stderr.log, never go on unconfined
        os.write(2, f"rapp sandbox: {type(e).__name__}: {e}\n".encode())
        os._exit(126)


def _enter(libc, new_root: Path, binds, tmpfs_mb: int) -> None:
    """Private mount namespace, a tmpfs root with the binds, chroot into it, cwd /app."""
    _check(libc.unshare(_CLONE_NEWNS), "unshare(mount namespace)")
    _check(libc.mount(b"none", b"/", None, _MS_REC | _MS_PRIVATE, None), "make mounts private")
    root = str(new_root).encode()
    _check(libc.mount(b"tmpfs", root, b"tmpfs", _MS_NOSUID | _MS_NODEV,
                      f"size={tmpfs_mb}m,mode=0755".encode()), "tmpfs root")
    for link in ("bin", "sbin", "lib", "lib64", "lib32", "libx32"):  # merged-/usr symlinks
        if os.path.islink(f"/{link}"):
            os.symlink(os.readlink(f"/{link}"), f"{new_root}/{link}")
    for src, target, writable in binds:
        dest = f"{new_root}{target}"
        if os.path.isdir(src):
            os.makedirs(dest, exist_ok=True)
        else:
            os.makedirs(os.path.dirname(dest), exist_ok=True)
            open(dest, "a").close()
        _check(libc.mount(src.encode(), dest.encode(), None, _MS_BIND | _MS_REC, None), f"bind {src}")
        flags = _MS_BIND | _MS_REMOUNT | _MS_NOSUID | (0 if writable else _MS_RDONLY)
        _check(libc.mount(None, dest.encode(), None, flags, None), f"remount {target}")
    tmp = f"{new_root}/tmp"
    os.makedirs(tmp, exist_ok=True)
    os.chmod(tmp, 0o1777)
    os.chroot(root)
    os.chdir(APP_DIR)
