"""What a RApp process does to itself at its start: the sandbox, from the inside (agents/sandbox.py
says what is asked, from the outside).

`confine()` is the first call of `python -m agents.runtime`, before anything of a RApp is read. A
sandboxed run becomes three processes:

    P  the process its Core or Platform started: never runs RApp code. It stays in the machine's
       network and PID namespaces and is the run's only way out: it forwards the RApp's XMPP
       connections to the server (one at a time), answers the RApp's forbidden system calls (a
       seccomp filter that notifies it: refused with EPERM, and told to the Core or Platform on
       the report pipe), and exits as its child F does.
    F  the init (PID 1) of a PID namespace of the run's own, in a user, mount, network, IPC and UTS
       namespace of its own: it builds the run's root (a tmpfs with read-only binds of the system,
       Python and the project; /app read-write), brings up loopback with listeners for P, drops
       every capability, sets no_new_privs and the seccomp filter, forks E and reaps orphans. When
       F ends, the kernel kills everything left in its PID namespace: whatever E's tree did
       (double fork, setsid) it cannot outlive its run.
    E  the runtime (agents/runtime.py) and the RApp: PID 2, its own uid, no capability.

Mode "root" (the Core or Platform runs as root): E's uid is a fresh one of the run, and the run's
control group (agents/cgroups.py) holds P, F and E. Mode "user" (no root): the same, with the user's
own uid mapped into the user namespace, and a control group only where one is delegated. Both go
through the same code below. Without user namespaces, root builds the same namespaces directly
and changes E's uid at the end ("userns": false).
"""
from __future__ import annotations

import ctypes
import errno
import json
import os
import selectors
import signal
import socket
import struct
import sys

CLONE_NEWNS, CLONE_NEWCGROUP, CLONE_NEWUTS, CLONE_NEWIPC = 0x20000, 0x02000000, 0x04000000, 0x08000000
CLONE_NEWUSER, CLONE_NEWPID, CLONE_NEWNET, CLONE_NEWTIME = 0x10000000, 0x20000000, 0x40000000, 0x80
NAMESPACE_FLAGS = (CLONE_NEWNS, CLONE_NEWCGROUP, CLONE_NEWUTS, CLONE_NEWIPC, CLONE_NEWUSER, CLONE_NEWPID,
                   CLONE_NEWNET, CLONE_NEWTIME)
MS_RDONLY, MS_NOSUID, MS_NODEV, MS_NOEXEC, MS_REMOUNT = 0x1, 0x2, 0x4, 0x8, 0x20
MS_NOATIME, MS_NODIRATIME, MS_BIND, MS_REC, MS_PRIVATE, MS_RELATIME = 0x400, 0x800, 0x1000, 0x4000, 0x40000, 0x200000
MNT_DETACH = 2
PR_SET_PDEATHSIG, PR_SET_DUMPABLE, PR_CAPBSET_DROP, PR_SET_NO_NEW_PRIVS, PR_CAP_AMBIENT = 1, 4, 24, 38, 47
PR_CAP_AMBIENT_CLEAR_ALL = 4
SIOCGIFFLAGS, SIOCSIFFLAGS, IFF_UP = 0x8913, 0x8914, 0x1
SECCOMP_IOCTL_NOTIF_RECV, SECCOMP_IOCTL_NOTIF_SEND = 0xC0502100, 0xC0182101
_NOTIF = struct.Struct("=QII" + "iIQ6Q")  # struct seccomp_notif: id, pid, flags, data (nr, arch, ip, args)
_NOTIF_RESP = struct.Struct("=QqiI")  # struct seccomp_notif_resp: id, val, error, flags
BASE = "/tmp"  # where the run's root is built (a tmpfs over it, in the run's own mount namespace)
APP_DIR = "/app"

# what a RApp never needs, refused (EPERM) and told: debugging other processes, the file-system
# tree, new namespaces, the kernel's BPF, keyrings, performance counters, kexec, modules, and what
# bypasses or weakens the others (io_uring's own path around seccomp, handles that reopen files by
# number, userfaultfd's stalls of the kernel)
DENIED = ("ptrace", "process_vm_readv", "process_vm_writev", "kcmp", "mount", "umount2", "pivot_root",
          "chroot", "open_tree", "move_mount", "fsopen", "fsconfig", "fsmount", "fspick", "mount_setattr",
          "unshare", "setns", "bpf", "keyctl", "add_key", "request_key", "perf_event_open", "kexec_load",
          "kexec_file_load", "init_module", "finit_module", "delete_module", "userfaultfd", "iopl", "ioperm",
          "reboot", "swapon", "swapoff", "acct", "name_to_handle_at", "open_by_handle_at", "quotactl",
          "io_uring_setup", "io_uring_enter", "io_uring_register", "personality", "syslog", "lookup_dcookie",
          "settimeofday", "clock_settime", "clock_adjtime", "adjtimex", "vhangup", "nfsservctl")


class SandboxSetupError(RuntimeError):
    pass


def _libc():
    return ctypes.CDLL(None, use_errno=True)  # the interpreter's own C library: no ldconfig run


def seccomp_library(path: str | None = None):
    """pyseccomp (libseccomp through ctypes), loaded from `path` when the caller found it already:
    its import looks libc and libseccomp up with ldconfig, two processes each run would start."""
    import ctypes.util

    if "pyseccomp" in sys.modules or not path:
        import pyseccomp
        return pyseccomp
    find = ctypes.util.find_library
    ctypes.util.find_library = lambda name: {"seccomp": path, "c": "libc.so.6"}.get(name) or find(name)
    try:
        import pyseccomp
    finally:
        ctypes.util.find_library = find
    return pyseccomp


def library_path() -> str | None:
    """Where libseccomp is (looked up once by the Core or Platform, for every run's sandbox)."""
    import ctypes.util
    return ctypes.util.find_library("seccomp")


def _check(ret: int, what: str) -> int:
    if ret == -1:
        err = ctypes.get_errno()
        raise OSError(err, f"{what}: {os.strerror(err)}")
    return ret


def _write(path: str, text: str) -> None:
    fd = os.open(path, os.O_WRONLY)
    try:
        os.write(fd, text.encode())
    finally:
        os.close(fd)


# -- P: before the namespaces ------------------------------------------------------------------
def sandboxed(asked: dict) -> None:
    """Build the run's sandbox around this process; returns only in E (the runtime goes on)."""
    lib = _libc()
    seccomp_library(asked.get("libseccomp"))
    for procs in asked.get("cgroup_procs", ()):  # P, F and E in the run's group (as root, or delegated)
        _write(procs, str(os.getpid()))
    last_cap = int(open("/proc/sys/kernel/cap_last_cap").read())
    if asked["userns"]:  # no root: the user's own uid, mapped into a user namespace of the run's
        uid, gid = os.geteuid(), os.getegid()
        _check(lib.unshare(CLONE_NEWUSER | CLONE_NEWPID), "unshare(user, pid namespaces)")
        _write("/proc/self/setgroups", "deny")
        _write("/proc/self/uid_map", f"{uid} {uid} 1\n")
        _write("/proc/self/gid_map", f"{gid} {gid} 1\n")
    else:  # root: F builds the namespaces as root and takes the run's uid at the end
        _check(lib.unshare(CLONE_NEWPID), "unshare(pid namespace)")
    ctl_p, ctl_f = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    ctl_p.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
    child = os.fork()
    if child:
        ctl_f.close()
        for fd in asked["child_fds"]:
            os.close(fd)
        os._exit(Monitor(child, ctl_p, asked).run())
    ctl_p.close()
    try:
        _init(lib, asked, ctl_f, last_cap)
    except BaseException as e:  # noqa: BLE001 - F's own failure: said in stderr.log, the run never starts
        os.write(2, f"rapp sandbox: {type(e).__name__}: {e}\n".encode())
        os._exit(126)


# -- F: PID 1 of the run -----------------------------------------------------------------------
def _init(lib, asked: dict, ctl: socket.socket, last_cap: int) -> None:
    _check(lib.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0), "parent-death signal")
    _check(lib.unshare(CLONE_NEWNS | CLONE_NEWNET | CLONE_NEWIPC | CLONE_NEWUTS), "unshare(mount, network, ipc, uts)")
    if asked.get("report_fd") is not None:  # the sandbox's events are P's to write, never the RApp's
        os.close(asked["report_fd"])
    hostname = b"rapp"
    lib.sethostname(hostname, len(hostname))
    _loopback_up()
    listeners = []
    for inner_host, inner_port, _, _ in asked["xmpp"]:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((inner_host, inner_port))
        s.listen(8)
        listeners.append(s)
    socket.send_fds(ctl, [b"listeners"], [s.fileno() for s in listeners])
    for s in listeners:
        s.close()
    _build_root(lib, asked["binds"], asked["tmpfs_mb"])
    if not asked["userns"]:  # root: the run's own uid now, every capability gone with it
        uid = asked["uid"]
        for cap in range(last_cap + 1):
            lib.prctl(PR_CAPBSET_DROP, cap, 0, 0, 0)
        os.setgroups([])
        os.setresgid(uid, uid, uid)
        os.setresuid(uid, uid, uid)
        _check(lib.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0), "parent-death signal")  # the uid change cleared it
    _drop_capabilities(lib, last_cap)
    _check(lib.prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0), "no_new_privs")
    notify_fd = _seccomp()
    socket.send_fds(ctl, [b"seccomp"], [notify_fd])
    os.close(notify_fd)
    if _parent_gone(ctl):
        os._exit(125)
    wake_r, wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    runtime = os.fork()
    if runtime == 0:  # E
        signal.set_wakeup_fd(-1)
        for sig in (signal.SIGCHLD, signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, signal.SIG_DFL)
        os.close(wake_r)
        os.close(wake_w)
        ctl.send(b"runtime")  # P learns E's pid as its own namespace numbers it (SO_PASSCRED)
        ctl.close()
        if asked["nice"]:
            os.nice(asked["nice"])
        return
    os._exit(_reap(runtime, ctl, wake_r))


def _parent_gone(ctl: socket.socket) -> bool:
    """P closed its end (it died before F's parent-death signal was armed)."""
    ctl.setblocking(False)
    try:
        return ctl.recv(1, socket.MSG_PEEK) == b""
    except BlockingIOError:
        return False
    finally:
        ctl.setblocking(True)


def _reap(runtime: int, ctl: socket.socket, wake_r: int) -> int:
    """F's life after E's start: reap every process reparented to it; when E exits, tell P how, and
    end (the kernel then kills what is left in the namespace). Ends too if P goes."""
    sel = selectors.DefaultSelector()
    sel.register(ctl, selectors.EVENT_READ)
    sel.register(wake_r, selectors.EVENT_READ)
    while True:
        for key, _ in sel.select():
            if key.fileobj is ctl:
                try:
                    if ctl.recv(16) == b"":
                        return 137  # P is gone: so is the run
                except OSError:
                    return 137
            else:
                try:
                    os.read(wake_r, 512)
                except BlockingIOError:
                    pass
        while True:
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                return 0
            if pid == 0:
                break
            if pid == runtime:
                how = {"signal": os.WTERMSIG(status)} if os.WIFSIGNALED(status) else {"exit": os.WEXITSTATUS(status)}
                try:
                    ctl.send(b"status" + json.dumps(how).encode())
                except OSError:
                    pass
                return how.get("exit", 128 + how.get("signal", 0))


def _loopback_up() -> None:
    import fcntl

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        req = struct.pack("16sH14x", b"lo", 0)
        flags = struct.unpack("16sH14x", fcntl.ioctl(s.fileno(), SIOCGIFFLAGS, req))[1]
        fcntl.ioctl(s.fileno(), SIOCSIFFLAGS, struct.pack("16sH14x", b"lo", flags | IFF_UP))


def _build_root(lib, binds, tmpfs_mb: int) -> None:
    """A tmpfs over BASE with the binds (and the run's directory, F's cwd, as /app), made the root
    (pivot_root); the machine's root detached."""
    _check(lib.mount(b"none", b"/", None, MS_REC | MS_PRIVATE, None), "make mounts private")
    app = os.open(".", os.O_PATH | os.O_DIRECTORY | os.O_CLOEXEC)  # a warm worker's directory is renamed later
    # every source held open before the tmpfs covers BASE: a checkout or virtualenv under /tmp would
    # be hidden by it (a bind of /tmp/x/.venv failed with "No such file or directory")
    held = [(os.open(source, os.O_PATH | os.O_CLOEXEC), os.path.isdir(source), target, writable)
            for source, target, writable in binds] + [(app, True, APP_DIR, True)]
    _check(lib.mount(b"tmpfs", BASE.encode(), b"tmpfs", MS_NOSUID | MS_NODEV,
                     f"size={tmpfs_mb}m,mode=0755".encode()), "tmpfs root")
    for link in ("bin", "sbin", "lib", "lib64", "lib32", "libx32"):  # merged-/usr symlinks
        if os.path.islink(f"/{link}"):
            os.symlink(os.readlink(f"/{link}"), f"{BASE}/{link}")
    for fd, is_dir, target, writable in held:
        dest = f"{BASE}{target}"
        if is_dir:
            os.makedirs(dest, exist_ok=True)
        else:
            os.makedirs(os.path.dirname(dest), exist_ok=True)
            os.close(os.open(dest, os.O_WRONLY | os.O_CREAT, 0o644))
        _check(lib.mount(f"/proc/self/fd/{fd}".encode(), dest.encode(), None, MS_BIND | MS_REC, None),
               f"bind {target}")
        flags = MS_BIND | MS_REMOUNT | MS_NOSUID | _locked_flags(dest) | (0 if writable else MS_RDONLY)
        _check(lib.mount(None, dest.encode(), None, flags, None), f"remount {target}")
    for fd, *_ in held:
        os.close(fd)
    os.makedirs(f"{BASE}/tmp", exist_ok=True)
    os.chmod(f"{BASE}/tmp", 0o1777)
    os.mkdir(f"{BASE}/.old")
    _check(lib.syscall(155, BASE.encode(), f"{BASE}/.old".encode()), "pivot_root")  # SYS_pivot_root (x86_64)
    os.chdir("/")
    _check(lib.umount2(b"/.old", MNT_DETACH), "detach the machine's root")
    os.rmdir("/.old")
    _check(lib.mount(None, b"/", None, MS_BIND | MS_REMOUNT | MS_NOSUID | MS_NODEV | MS_RDONLY, None), "root read-only")
    os.chdir(APP_DIR)


def _locked_flags(path: str) -> int:
    """The flags a bind keeps from its source (a user namespace may not clear them on remount)."""
    f = os.statvfs(path).f_flag
    out = 0
    for st, ms in ((os.ST_NODEV, MS_NODEV), (os.ST_NOEXEC, MS_NOEXEC), (os.ST_NOATIME, MS_NOATIME),
                   (os.ST_NODIRATIME, MS_NODIRATIME), (os.ST_RELATIME, MS_RELATIME)):
        if f & st:
            out |= ms
    return out


class _CapHeader(ctypes.Structure):
    _fields_ = [("version", ctypes.c_uint32), ("pid", ctypes.c_int)]


class _CapData(ctypes.Structure):
    _fields_ = [("effective", ctypes.c_uint32), ("permitted", ctypes.c_uint32), ("inheritable", ctypes.c_uint32)]


def _drop_capabilities(lib, last_cap: int) -> None:
    for cap in range(last_cap + 1):
        lib.prctl(PR_CAPBSET_DROP, cap, 0, 0, 0)  # EPERM once already dropped (the uid change): fine
    lib.prctl(PR_CAP_AMBIENT, PR_CAP_AMBIENT_CLEAR_ALL, 0, 0, 0)
    header, data = _CapHeader(0x20080522, 0), (_CapData * 2)()
    _check(lib.capset(ctypes.byref(header), data), "drop capabilities")


def _seccomp() -> int:
    """The filter: DENIED and namespace-making clones notify P (which refuses them); clone3 is
    ENOSYS (its flags are out of the filter's reach: the C library falls back to clone). Returns
    the notification descriptor."""
    sc = seccomp_library()
    flt = sc.SyscallFilter(sc.ALLOW)
    for name in DENIED:
        try:
            flt.add_rule(sc.NOTIFY, name)
        except (OSError, ValueError):  # not a system call of this architecture
            pass
    for flag in NAMESPACE_FLAGS:
        flt.add_rule(sc.NOTIFY, "clone", sc.Arg(0, sc.MASKED_EQ, flag, flag))
    flt.add_rule(sc.ERRNO(errno.ENOSYS), "clone3")
    flt.load()
    fd = sc._libseccomp.seccomp_notify_fd(flt._filter)  # noqa: SLF001 - pyseccomp keeps the context private
    if fd < 0:
        raise SandboxSetupError("seccomp gave no notification descriptor")
    return os.dup(fd)


def syscall_name(nr: int) -> str:
    try:
        import pyseccomp as sc
        return sc.resolve_syscall(sc.system_arch(), nr).decode()
    except Exception:  # noqa: BLE001
        return f"syscall {nr}"


# -- P's life after F's start -----------------------------------------------------------------
class Monitor:
    """P: forwards XMPP connections, refuses what the filter hands it, tells its Core or Platform
    (the report pipe, one JSON line an event) and exits as F did."""

    def __init__(self, child: int, ctl: socket.socket, asked: dict):
        self.child, self.ctl, self.asked = child, ctl, asked
        self.report_fd = asked.get("report_fd")
        if self.report_fd is not None:
            os.set_blocking(self.report_fd, False)  # never wait on the Core: an event is dropped instead
        self.targets = {(h, p): (rh, rp) for h, p, rh, rp in asked["xmpp"]}
        self.max_connections = asked.get("max_connections", 1)
        self.open_connections = 0
        self.status: dict | None = None
        self.refused: dict[str, int] = {}

    def run(self) -> int:
        lib = _libc()
        # after every change of credentials (which clears it): dies with its Core or Platform
        _check(lib.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0), "parent-death signal")
        if os.getppid() != self.asked["parent"]:
            return 125
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # the runtime logs out first (its group gets it)
        if self.asked["nice"]:  # the run's priority, its forwarding included
            os.nice(self.asked["nice"])
        self.sel = selectors.DefaultSelector()
        pidfd = os.pidfd_open(self.child)
        self.sel.register(pidfd, selectors.EVENT_READ, "child")
        self.sel.register(self.ctl, selectors.EVENT_READ, "ctl")
        while True:
            for key, events in self.sel.select():
                what = key.data
                if isinstance(what, _Link):
                    what(key.fileobj, events)
                elif what == "child":
                    return self._child_ended()
                elif what == "ctl":
                    self._from_init()
                elif what == "notify":
                    self._refuse(key.fd)
                else:
                    self._accept(key.fileobj, what)

    def _child_ended(self) -> int:
        _, status = os.waitpid(self.child, 0)
        self._drain_ctl()
        how = self.status or ({"signal": os.WTERMSIG(status)} if os.WIFSIGNALED(status)
                              else {"exit": os.WEXITSTATUS(status)})
        if "signal" in how:  # as the runtime ended (killed by a signal): its Core reads -N as before
            sig = how["signal"]
            if sig not in (signal.SIGKILL, signal.SIGSTOP):  # those two have no handler to reset
                signal.signal(sig, signal.SIG_DFL)
            os.kill(os.getpid(), sig)
        return how.get("exit", 1)

    def _drain_ctl(self) -> None:
        self.ctl.setblocking(False)
        try:
            while self._from_init():
                pass
        except (BlockingIOError, OSError):
            pass

    def _from_init(self) -> bool:
        msg, fds = self._recv()
        if not msg:
            if self.ctl.fileno() in self.sel.get_map():
                self.sel.unregister(self.ctl)
            return False
        if msg == b"listeners":
            for fd, (h, p) in zip(fds, self.targets):
                s = socket.socket(fileno=fd)
                s.setblocking(False)
                self.sel.register(s, selectors.EVENT_READ, (h, p))
        elif msg == b"seccomp":
            self.sel.register(fds[0], selectors.EVENT_READ, "notify")
        elif msg.startswith(b"status"):
            self.status = json.loads(msg[6:])
        return True

    def _recv(self):
        """A message of F or E: (bytes, descriptors, the sender's pid); E's says its pid."""
        fds = []
        msg, anc, _, _ = self.ctl.recvmsg(4096, socket.CMSG_SPACE(8 * 4) + socket.CMSG_SPACE(12))
        pid = None
        for level, kind, data in anc:
            if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
                fds += list(struct.unpack(f"{len(data) // 4}i", data[:len(data) - len(data) % 4]))
            elif level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS:
                pid = struct.unpack("3i", data[:12])[0]
        if msg == b"runtime" and pid:
            self.report({"event": "runtime", "pid": pid})
        return msg, fds

    def report(self, event: dict) -> None:
        if self.report_fd is None:
            return
        try:
            os.write(self.report_fd, (json.dumps(event) + "\n").encode()[:4096])
        except OSError:
            pass

    def _refuse(self, fd: int) -> None:
        import fcntl

        buf = bytearray(_NOTIF.size)
        try:
            fcntl.ioctl(fd, SECCOMP_IOCTL_NOTIF_RECV, buf, True)
        except OSError as e:
            if e.errno == errno.ENOENT:  # the caller went away meanwhile
                return
            self.sel.unregister(fd)
            return
        notif_id, pid, _, nr = _NOTIF.unpack(bytes(buf))[:4]
        try:
            fcntl.ioctl(fd, SECCOMP_IOCTL_NOTIF_SEND, bytearray(_NOTIF_RESP.pack(notif_id, 0, -errno.EPERM, 0)), True)
        except OSError:
            pass
        name = syscall_name(nr)
        self.refused[name] = self.refused.get(name, 0) + 1
        if self.refused[name] <= 3 or self.refused[name] in (10, 100, 1000):  # a loop is told, not each call
            self.report({"event": "refused", "what": f"system call {name}", "count": self.refused[name]})

    def _accept(self, listener: socket.socket, inner) -> None:
        try:
            conn, _ = listener.accept()
        except OSError:
            return
        if self.open_connections >= self.max_connections:
            conn.close()
            self.report({"event": "refused", "what": "a second XMPP connection",
                         "why": f"a RApp process holds {self.max_connections} at a time"})
            return
        # the server asked for first, then the domain's other nodes (a cluster's fallbacks): a node
        # that is down is then passed over here, as a client outside would pass it over itself
        first = self.targets[inner]
        candidates = [first] + [t for t in dict.fromkeys(self.targets.values()) if t != first]
        self.open_connections += 1
        _Link(self, conn, candidates).dial()

    def upstream_failed(self, target, error) -> None:
        self.report({"event": "upstream", "error": f"{target[0]}:{target[1]}: {error}"})

    def closed(self, link: "_Link") -> None:
        self.open_connections -= 1


class _Link:
    """One forwarded connection, both ways, in P's selector loop (P cannot start threads: it made a
    PID namespace for its children, and a thread is a child too)."""

    def __init__(self, monitor: Monitor, inner: socket.socket, candidates: list):
        self.monitor, self.sel = monitor, monitor.sel
        self.inner, self.candidates = inner, list(candidates)
        inner.setblocking(False)
        self.up = None
        self.shut = set()  # sockets whose peer side ended (no more to read from them)
        self.connected = False

    def dial(self) -> None:
        """Connect upstream to the next candidate server; none left: the inner connection ends."""
        while self.candidates:
            self.target = self.candidates.pop(0)
            up = socket.socket(socket.AF_INET6 if ":" in self.target[0] else socket.AF_INET, socket.SOCK_STREAM)
            up.setblocking(False)
            try:
                up.connect_ex(self.target)
            except OSError as e:  # a name that does not resolve (connect_ex raises then)
                up.close()
                self.monitor.upstream_failed(self.target, e)
                continue
            self.up = up
            self.pending = {self.inner: b"", up: b""}  # bytes waiting to be written to that socket
            self.sel.register(up, selectors.EVENT_WRITE, self)
            return
        self.inner.close()
        self.monitor.closed(self)

    def __call__(self, sock: socket.socket, events: int) -> None:
        if not self.connected:
            err = self.up.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
            if err:
                self._want(self.up, 0)
                self.up.close()
                self.monitor.upstream_failed(self.target, os.strerror(err))
                self.dial()
                return
            self.connected = True
            for sock in (self.inner, self.up):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._update()
            return
        other = self.up if sock is self.inner else self.inner
        if events & selectors.EVENT_WRITE:
            self._flush(sock)
        if events & selectors.EVENT_READ and sock not in self.shut:
            try:
                data = sock.recv(262144)
            except BlockingIOError:
                data = None
            except OSError:
                data = b""
            if data:
                self.pending[other] += data
                self._flush(other)
            elif data == b"":
                self.shut.add(sock)
                if not self.pending[other]:
                    _shutdown(other, socket.SHUT_WR)
        self._update()

    def _flush(self, sock: socket.socket) -> None:
        data = self.pending[sock]
        if not data:
            return
        try:
            n = sock.send(data)
        except BlockingIOError:
            n = 0
        except OSError:
            self.shut.update((self.inner, self.up))
            self.pending = {self.inner: b"", self.up: b""}
            return
        self.pending[sock] = data[n:]
        source = self.up if sock is self.inner else self.inner
        if not self.pending[sock] and source in self.shut:
            _shutdown(sock, socket.SHUT_WR)

    def _update(self) -> None:
        if {self.inner, self.up} <= self.shut and not any(self.pending.values()):
            for sock in (self.inner, self.up):
                self._want(sock, 0)
                sock.close()
            self.monitor.closed(self)
            return
        for sock in (self.inner, self.up):
            other = self.up if sock is self.inner else self.inner
            # read while the other side's queue is short (back-pressure), write while one is queued
            self._want(sock, (selectors.EVENT_READ if sock not in self.shut and len(self.pending[other]) < 1 << 20
                              else 0) | (selectors.EVENT_WRITE if self.pending[sock] else 0))

    def _want(self, sock: socket.socket, events: int) -> None:
        known = sock.fileno() in self.sel.get_map() if sock.fileno() >= 0 else False
        if not events:
            if known:
                self.sel.unregister(sock)
        elif known:
            self.sel.modify(sock, events, self)
        else:
            self.sel.register(sock, events, self)


def _shutdown(s: socket.socket, how: int) -> None:
    try:
        s.shutdown(how)
    except OSError:
        pass


def unconfined(asked: dict) -> None:
    """No namespaces ("off": the kernel allows none, and the user allowed that): rlimits, the
    parent-death signal, the priority."""
    lib = _libc()
    _check(lib.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0), "parent-death signal")
    if os.getppid() != asked["parent"]:
        os._exit(125)
    if asked["nice"]:
        os.nice(asked["nice"])
