"""The sandbox a RApp process (Dynamic or Cloud Agent) runs in, from the outside: what is asked for
each run, what this machine offers, and the files of a run a trusted process touches.

A RApp process confines itself first thing, before it reads its spec or imports anything of a RApp
(agents/confine.py, from what `Sandbox.confinement` put in its environment):
1. rlimits (agents/process.py `Limits`) and a control group of the run's own (agents/cgroups.py:
   memory, processes, CPU; `cgroup.kill` at its end) where the machine offers one;
2. user, PID, mount, network, IPC and UTS namespaces of its own: the run's root is a tmpfs holding
   only read-only binds of the system (/usr, /etc, the shared-library symlinks), the Python
   installation and virtualenv, the project's own packages, a minimal /dev and the run's directory
   (read-write, as /app); no /proc, no /tmp of the machine, no agent's data or credentials; its
   only network is loopback, where its Core's or Platform's side of the sandbox forwards the XMPP
   server's port (one connection at a time), nothing else;
3. its own uid (root: a fresh one per run, never an account of the machine; no root: the user's,
   mapped into the user namespace), no capability, no_new_privs, and a seccomp filter whose
   refusals (ptrace, mount, namespaces, bpf, keyrings, perf, kexec, modules...) are told to the
   Core or Platform; the run's PID namespace dies with its init, whatever its processes did.

Modes: "root" (the Core or Platform runs as root, as a robot's service does), "user" (no root: the
same through user namespaces, so a developer's `rapp run rapp` runs as it will in deployment), and
"off" (the kernel allows no user namespace: rlimits and the scrubbed environment only, which needs
--allow-unsandboxed, with the reason printed). `probe()` finds the mode once.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import logging
import os
import secrets
import stat
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

log = logging.getLogger("rapp.sandbox")

UID_BASE = 0x5AF0_0000  # sandbox uids: UID_BASE .. UID_BASE + 2**20, no account of the machine
APP_DIR = "/app"
DEVICES = ("null", "zero", "random", "urandom")
SYSTEM = ("/usr", "/etc")
PROJECT_PACKAGES = ("agents", "behaviours", "ontology", "robots", "rapps", "xmpp_server")
ENV_ALLOWED = ("PATH", "LANG", "LC_ALL", "LC_CTYPE", "TZ")
# glibc's malloc maps allocations from 128 kB up on their own, unmapped when freed: by default it raises
# that threshold to each large block freed, after which a Cloud Agent's decoded frames come from the
# heap, which keeps them (robots/render_process.py does the same for the renders, bench/RESULTS.md)
MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": str(128 * 1024)}
INNER_HOST = "127.0.0.1"  # where the run's XMPP server is, inside its network namespace
MODES = ("root", "user", "off")
ALLOW_UNSANDBOXED_ENV = "RAPP_ALLOW_UNSANDBOXED"


class SandboxError(RuntimeError):
    pass


class SandboxUnavailable(SandboxError):
    pass


@dataclass(frozen=True)
class Probe:
    mode: str  # "root", "user" or "off"
    userns: bool  # the sandbox goes through a user namespace ("user"; root builds the namespaces itself)
    reason: str  # why "off"


_PROBE = r"""
import ctypes, os, sys
lib = ctypes.CDLL(None, use_errno=True)
def fail(what):
    e = ctypes.get_errno(); print(f"{what}: {os.strerror(e)}", end=""); sys.exit(1)
try:
    import pyseccomp
except Exception as e:
    print(f"no seccomp library: {type(e).__name__}: {e}", end=""); sys.exit(1)
userns = sys.argv[1] == "1"
if userns:
    uid, gid = os.geteuid(), os.getegid()
    if lib.unshare(0x10000000 | 0x20000000): fail("unshare(user, pid namespaces)")
    for name, text in (("setgroups", "deny"), ("uid_map", f"{uid} {uid} 1"), ("gid_map", f"{gid} {gid} 1")):
        with open(f"/proc/self/{name}", "w") as f: f.write(text)
elif lib.unshare(0x20000000): fail("unshare(pid namespace)")
pid = os.fork()
if pid == 0:
    if lib.unshare(0x20000 | 0x40000000 | 0x08000000 | 0x04000000): fail("unshare(mount, network, ipc, uts)")
    if lib.mount(b"none", b"/", None, 0x4000 | 0x40000, None): fail("private mounts")
    if lib.mount(b"tmpfs", b"/tmp", b"tmpfs", 0, b"size=1m"): fail("tmpfs")
    os._exit(0)
sys.exit(os.waitpid(pid, 0)[1] >> 8)
"""


def _try_probe(userns: bool) -> tuple[bool, str]:
    try:
        run = subprocess.run([sys.executable, "-c", _PROBE, "1" if userns else "0"], timeout=20,
                             capture_output=True, text=True, env={"PATH": os.environ.get("PATH", "/usr/bin:/bin")})
    except (OSError, subprocess.TimeoutExpired) as e:
        return False, f"{type(e).__name__}: {e}"
    return run.returncode == 0, (run.stdout or run.stderr).strip()[-300:]


def _userns_hint() -> str:
    for path, bad, why in (("/proc/sys/user/max_user_namespaces", "0", "user.max_user_namespaces is 0"),
                           ("/proc/sys/kernel/unprivileged_userns_clone", "0", "kernel.unprivileged_userns_clone is 0"),
                           ("/proc/sys/kernel/apparmor_restrict_unprivileged_userns", "1",
                            "AppArmor restricts unprivileged user namespaces")):
        try:
            if Path(path).read_text().strip() == bad:
                return f" ({why})"
        except OSError:
            pass
    return ""


@functools.lru_cache(maxsize=1)
def probe() -> Probe:
    """What sandbox this process can build, tried once in throwaway children."""
    if not sys.platform.startswith("linux"):
        return Probe("off", False, f"namespaces are Linux's; this is {sys.platform}")
    if os.geteuid() == 0:
        ok, why = _try_probe(userns=False)
        return Probe("root", False, "") if ok else Probe("off", False, f"the kernel refused the sandbox's namespaces: {why}")
    ok, why = _try_probe(userns=True)
    if ok:
        return Probe("user", True, "")
    return Probe("off", False, f"the kernel refused a user namespace to this user: {why}{_userns_hint()}")


def available() -> bool:
    """Whether this process can sandbox RApps (as root, or through user namespaces)."""
    return probe().mode != "off"


def default_mode() -> str:
    """The best sandbox here; "off" only where the kernel allows none AND the user allowed running
    RApps unsandboxed (RAPP_ALLOW_UNSANDBOXED=1, `--allow-unsandboxed`): SandboxUnavailable else."""
    found = probe()
    if found.mode == "off" and os.environ.get(ALLOW_UNSANDBOXED_ENV) != "1":
        raise SandboxUnavailable(f"RApps cannot be sandboxed here: {found.reason}; "
                                 "--allow-unsandboxed runs them with this user's rights (development only)")
    return found.mode


@functools.lru_cache(maxsize=1)
def describe() -> str:
    """One line: the sandbox this machine gives RApps, and what is missing (said once at start)."""
    from .cgroups import support

    found = probe()
    if found.mode == "off":
        return f"RApp sandbox: OFF ({found.reason})"
    who = "a fresh uid per run" if found.mode == "root" else "the user's uid"
    ns = "user, pid, mount, network, ipc, uts namespaces" if found.userns else "pid, mount, network, ipc, uts namespaces"
    text = f"RApp sandbox: {found.mode} ({who}; {ns}; seccomp); {support().describe()}"
    if found.reason:
        text += f"; {found.reason}"
    return text


def allow_unsandboxed(asked: bool, prog: str) -> bool:
    """A command's --allow-unsandboxed: the sandbox is used wherever the kernel allows one (the flag
    then changes nothing); where it allows none, the run goes on unsandboxed only if asked, with the
    reason printed either way. False: refused (the caller exits)."""
    found = probe()
    if found.mode != "off":
        if asked:
            print(f"{prog}: --allow-unsandboxed ignored: RApps are sandboxed here ({found.mode} mode)",
                  file=sys.stderr, flush=True)
        return True
    if not asked:
        print(f"{prog}: RApps cannot be sandboxed on this machine: {found.reason}. --allow-unsandboxed runs "
              "them with this user's rights (development only)", file=sys.stderr, flush=True)
        return False
    os.environ[ALLOW_UNSANDBOXED_ENV] = "1"
    print(f"WARNING: {prog}: RApps run UNSANDBOXED, with this user's rights: {found.reason}", file=sys.stderr, flush=True)
    return True


def say_once() -> None:
    """Log the sandbox's line once per process, as a warning when something is missing."""
    if getattr(say_once, "done", False):
        return
    say_once.done = True
    from .cgroups import support

    line = describe()
    (log.warning if (probe().mode == "off" or support().missing or probe().reason) else log.info)(line)


@functools.lru_cache(maxsize=1)
def _libseccomp() -> str | None:
    from .confine import library_path
    return library_path()


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
    """How RApp processes are confined (`mode`: "root", "user" or "off", agents/confine.py); by
    default the best this machine allows (`default_mode`)."""

    mode: str = field(default_factory=default_mode)
    tmpfs_mb: int = 256  # /app/tmp and the sandbox root live in RAM: capped
    max_connections: int = 1  # XMPP connections a RApp process may hold at once (its agent's)
    packages: tuple[str, ...] = PROJECT_PACKAGES  # the project's packages bound (a Store build's tests: more)
    extra_binds: tuple[tuple[str, str, bool], ...] = ()  # (source, target, writable): a Store build's /dev/shm

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"sandbox mode must be one of {MODES}, not {self.mode!r}")
        if self.enabled:
            say_once()

    @property
    def enabled(self) -> bool:
        return self.mode != "off"

    @property
    def userns(self) -> bool:
        return self.mode == "user"

    def xmpp_routes(self, settings) -> list[tuple[str, int, str, int]]:
        """(host, port inside the sandbox, the server's host, port) for the server and each fallback."""
        out, taken = [], set()
        for host, port in settings.addresses():
            inner, n = INNER_HOST, 1
            while (inner, port) in taken:
                n += 1
                inner = f"127.0.0.{n}"
            taken.add((inner, port))
            out.append((inner, port, host, port))
        return out

    def env(self, settings, extra: dict[str, str] | None = None) -> dict[str, str]:
        """The child's whole environment: an allow-list, never a copy of the parent's. Sandboxed,
        the XMPP server is reached on loopback inside the run's network namespace."""
        env = {k: os.environ[k] for k in ENV_ALLOWED if k in os.environ}
        env.setdefault("PATH", "/usr/local/bin:/usr/bin:/bin")
        env.update(PYTHONPATH=str(_project_root()), PYTHONDONTWRITEBYTECODE="1", PYTHONNOUSERSITE="1", **MALLOC_ENV)
        if self.enabled:
            env.update(HOME=APP_DIR, TMPDIR=f"{APP_DIR}/tmp", MPLCONFIGDIR=f"{APP_DIR}/tmp")
        env.update(settings.to_env(fields=("host", "port", "fallback", "domain", "auto_register",
                                            "verify_tls", "force_xmpp", "start_timeout")))
        if self.enabled:
            routes = self.xmpp_routes(settings)
            env.update(RAPP_XMPP_HOST=routes[0][0], RAPP_XMPP_PORT=str(routes[0][1]))
            if len(routes) > 1:
                env["RAPP_XMPP_FALLBACK"] = ",".join(f"{h}:{p}" for h, p, _, _ in routes[1:])
        env.update(extra or {})
        return env

    def new_uid(self) -> int | None:
        """A fresh uid for a run (root mode); None where runs keep the user's own."""
        return UID_BASE + secrets.randbelow(1 << 20) if self.mode == "root" else None

    def prepare(self, workdir: Path, uid: int | None) -> None:
        """Give the run's directory to its uid (0700): no other run can read it."""
        workdir.mkdir(parents=True, exist_ok=True)
        (workdir / "tmp").mkdir(exist_ok=True)
        if uid is None:
            return
        give_tree(workdir, uid)
        os.chmod(workdir, 0o700)

    def confinement(self, uid: int | None, limits, nice: int = 0, *, settings=None, cgroup=None,
                    report_fd: int | None = None, child_fds: tuple[int, ...] = ()) -> str:
        """What a RApp process applies to itself at its start (agents/confine.py), for its
        environment (CONFINE_ENV). Not a `preexec_fn`: with one, CPython cannot vfork, and the fork of
        a large Core or Platform (50 ms for a Platform's 220 MB) holds the GIL, and the logging
        modules' at-fork locks, all along: the parent's event loop stood still for each spawn.
        `report_fd`: the sandbox's events for its Core/Platform; `child_fds`: the runtime's pipes
        (the sandbox's outer process closes its copies)."""
        asked = {"mode": self.mode, "uid": uid, "tmpfs_mb": self.tmpfs_mb, "nice": nice,
                 "limits": dataclasses.asdict(limits), "parent": os.getpid()}
        if self.enabled:
            asked.update(userns=self.userns, binds=self._binds(), libseccomp=_libseccomp(), report_fd=report_fd, child_fds=list(child_fds),
                         xmpp=self.xmpp_routes(settings) if settings is not None else [],
                         max_connections=self.max_connections,
                         cgroup_procs=cgroup.procs_files() if cgroup is not None else [])
        return json.dumps(asked)

    def _binds(self) -> list[tuple[str, str, bool]]:
        """(source, target inside the sandbox, writable) for every bind of the sandbox's root."""
        root = _project_root()
        out = [(p, p, False) for p in SYSTEM if os.path.isdir(p)]
        out += [(p, p, False) for p in _python_dirs() if not any(p.startswith(s + "/") for s in SYSTEM)]
        out += [(str(root / pkg), str(root / pkg), False) for pkg in self.packages if (root / pkg).is_dir()]
        out += [(f"/dev/{d}", f"/dev/{d}", True) for d in DEVICES if os.path.exists(f"/dev/{d}")]
        return out + list(self.extra_binds)  # and the run's directory as /app: the process's cwd (agents/confine.py)


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
    done): rlimits and the priority, then the sandbox (agents/confine.py), which returns in the
    runtime's own process only. Before any RApp code: the runtime calls it first thing. Any failure
    ends the process (126), with the reason in its stderr.log: it never goes on unconfined."""
    raw = os.environ.pop(CONFINE_ENV, None)
    if raw is None:
        return
    try:
        from . import confine as inside
        from .limits import Limits
        from .priority import set_group_nice

        asked = json.loads(raw)
        if asked["nice"]:  # its session's group, while it may (no rate limit as root); its threads' later
            set_group_nice(os.getpid(), os.getpriority(os.PRIO_PROCESS, 0) + asked["nice"])
        Limits(**asked["limits"]).apply(own_uid=asked["mode"] != "off")
        if asked["mode"] == "off":
            inside.unconfined(asked)
        else:
            inside.sandboxed(asked)
    except BaseException as e:  # noqa: BLE001 - say why in stderr.log, never go on unconfined
        os.write(2, f"rapp sandbox: {type(e).__name__}: {e}\n".encode())
        os._exit(126)


# -- what a trusted process copies out of a run --------------------------------------------------
MAX_COPY_FILE = 64 * 1024**2
MAX_COPY_TOTAL = 256 * 1024**2
MAX_COPY_FILES = 10_000


def copy_outputs(src: str | Path, dest: str | Path, *, owner: int | None = None, max_file: int = MAX_COPY_FILE,
                 max_total: int = MAX_COPY_TOTAL, max_files: int = MAX_COPY_FILES) -> tuple[list[str], list[str]]:
    """A run's output directory (the RApp's to fill) copied by a trusted process: regular files only,
    opened without following any link (O_NOFOLLOW, and by directory descriptors: a directory swapped
    for a link is not walked), one link only (a hard link to a file elsewhere is not copied), owned
    by the run's uid where it had one, each and all size-capped. Never raises: (copied, skipped with
    why), paths relative to dest."""
    copied: list[str] = []
    skipped: list[str] = []
    total = 0
    dest = Path(dest)
    try:
        top = os.open(src, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    except OSError as e:
        return [], [f".: {e.strerror or e}"]
    try:
        stack = [(top, "")]
        while stack:
            dirfd, rel = stack.pop()
            try:
                names = sorted(os.listdir(dirfd))
            except OSError as e:
                skipped.append(f"{rel or '.'}: {e.strerror}")
                names = []
            for name in names:
                path = f"{rel}{name}"
                if len(copied) + len(skipped) >= max_files:
                    skipped.append(f"{path}: more than {max_files} entries")
                    break
                try:
                    st = os.stat(name, dir_fd=dirfd, follow_symlinks=False)
                    if stat.S_ISDIR(st.st_mode):
                        if owner is not None and st.st_uid != owner:
                            raise _Skip("not the run's")
                        sub = os.open(name, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW, dir_fd=dirfd)
                        stack.append((sub, path + "/"))
                        continue
                    total += _copy_one(dirfd, name, dest / path, st, owner, max_file, max_total - total)
                    copied.append(path)
                except _Skip as e:
                    skipped.append(f"{path}: {e}")
                except OSError as e:
                    skipped.append(f"{path}: {e.strerror or e}")
            if dirfd != top:
                os.close(dirfd)
    except Exception as e:  # noqa: BLE001 - the copy never brings its caller down
        skipped.append(f"copy stopped: {type(e).__name__}: {e}")
    finally:
        os.close(top)
    return copied, skipped


class _Skip(Exception):
    pass


def _copy_one(dirfd: int, name: str, to: Path, st, owner: int | None, max_file: int, room: int) -> int:
    if stat.S_ISLNK(st.st_mode):
        raise _Skip("a symbolic link")
    if not stat.S_ISREG(st.st_mode):
        raise _Skip("not a regular file")
    if st.st_nlink != 1:
        raise _Skip("a hard link")
    if owner is not None and st.st_uid != owner:
        raise _Skip("not the run's")
    if st.st_size > min(max_file, room):
        raise _Skip(f"{st.st_size} bytes: over the cap of {min(max_file, room)}")
    fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK, dir_fd=dirfd)
    try:
        again = os.fstat(fd)
        if (again.st_ino, again.st_dev) != (st.st_ino, st.st_dev) or not stat.S_ISREG(again.st_mode):
            raise _Skip("changed while copied")
        to.parent.mkdir(parents=True, exist_ok=True)
        out = os.open(to, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o644)
        n = 0
        try:
            while n <= max_file:
                chunk = os.read(fd, 1 << 20)
                if not chunk:
                    break
                os.write(out, chunk)
                n += len(chunk)
        finally:
            os.close(out)
        if n > min(max_file, room):
            os.unlink(to)
            raise _Skip("grew over the cap while copied")
        return n
    finally:
        os.close(fd)
