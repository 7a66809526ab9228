"""A control group per RApp run: its memory, process and CPU limits, and one write that kills it.

What a machine offers varies, so it is found once (`support()`) and said once at start
(`Support.describe`):
- cgroup v2 (a `cgroup2` mount): a run's group under `<v2 root>/rapp-sandbox/`; `cgroup.kill`
  (Linux 5.14) kills every process in it at once, wherever it forked to. Its memory, pids and cpu
  controllers give the limits where they are enabled for the sandbox's group.
- cgroup v1 (a host in "hybrid" mode mounts each controller on its own): the memory, pids and cpu
  controllers v2 does not hold give the limits there, under this process's own group of each.
- Neither writable (no root, no delegated subtree): no group. The run's PID namespace still ends
  with its init (agents/confine.py), and the rlimits stay; the Core and Platform say so at start.

A run's weight follows its nice value: a process in a CPU group of its own is no longer scheduled
by autogroup (agents/priority.py), so the group's weight stands in for its session's nice.
"""
from __future__ import annotations

import errno
import functools
import itertools
import os
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path

SANDBOX_GROUP = "rapp-sandbox"
V1_CONTROLLERS = ("memory", "pids", "cpu")
CPU_PERIOD_US = 100_000
# the kernel's weight of each nice value (kernel/sched/core.c sched_prio_to_weight), from nice 0 to 19
# the group's process limit stands above the runtime's RLIMIT_NPROC by this much: the group also holds
# the sandbox's own two processes (agents/confine.py P and F), and the rlimit says "try again" first
PIDS_SLACK = 16
NICE_WEIGHT = (1024, 820, 655, 526, 423, 335, 272, 215, 172, 137, 110, 87, 70, 56, 45, 36, 29, 23, 18, 15)


def _mounts() -> list[tuple[str, str, str]]:
    """(mount point, type, options) of every cgroup mount."""
    out = []
    try:
        with open("/proc/self/mounts") as f:
            for line in f:
                parts = line.split()
                if len(parts) >= 4 and parts[2] in ("cgroup", "cgroup2"):
                    out.append((parts[1], parts[2], parts[3]))
    except OSError:
        pass
    return out


def _own_paths() -> dict[str, str]:
    """This process's group in each hierarchy: "" for v2, the controller names for v1."""
    out = {}
    try:
        with open("/proc/self/cgroup") as f:
            for line in f:
                _, names, path = line.rstrip("\n").split(":", 2)
                for name in (names.split(",") if names else [""]):
                    out[name] = path
    except OSError:
        pass
    return out


def _read(path: Path) -> str:
    try:
        return path.read_text().strip()
    except OSError:
        return ""


def _writable(path: Path) -> bool:
    return path.is_dir() and os.access(path, os.W_OK) and os.access(path / "cgroup.procs", os.W_OK)


@dataclass(frozen=True)
class Support:
    """Where run groups go: a v2 base (with the controllers it enables there) and v1 bases."""

    v2: Path | None = None  # <v2 root>/rapp-sandbox (or this user's delegated group's)
    v2_controllers: frozenset[str] = frozenset()
    v1: dict[str, Path] = field(default_factory=dict)  # controller -> <mount>/<own group>/rapp-sandbox
    missing: tuple[str, ...] = ()  # what is not there, in words
    kill: bool = False  # `cgroup.kill` ends a run's v2 group at once (Linux 5.14)

    def limits(self) -> set[str]:
        return set(self.v2_controllers) | set(self.v1)

    def any(self) -> bool:
        return self.v2 is not None or bool(self.v1)

    def ensure_bases(self) -> None:
        """The base groups made (again: `release` removes them when the last run's group is gone),
        with the v2 controllers enabled for their children."""
        for base in self.bases():
            base.mkdir(exist_ok=True)
        for name in sorted(self.v2_controllers):
            (self.v2 / "cgroup.subtree_control").write_text(f"+{name}")

    def bases(self) -> list[Path]:
        return ([self.v2] if self.v2 is not None else []) + list(self.v1.values())

    def release(self) -> None:
        """The base groups removed where empty: nothing of the sandbox is left in this process's own
        group (whoever made that group may want to remove it)."""
        for base in self.bases():
            try:
                base.rmdir()
            except OSError:
                pass

    def describe(self) -> str:
        parts = []
        if self.v2 is not None:
            parts.append(f"cgroup v2 at {self.v2}" + (" (cgroup.kill)" if self.kill else " (no cgroup.kill)")
                         + (f" limiting {', '.join(sorted(self.v2_controllers))}" if self.v2_controllers else ""))
        if self.v1:
            parts.append(f"cgroup v1 limiting {', '.join(sorted(self.v1))}")
        text = "; ".join(parts) if parts else "no cgroup"
        if self.missing:
            text += "; missing: " + "; ".join(self.missing)
        return text


@functools.lru_cache(maxsize=1)
def support() -> Support:
    """What this process can use, found once (creating the sandbox's base groups where it may)."""
    mounts, own = _mounts(), _own_paths()
    missing: list[str] = []
    v2 = v2_controllers = None
    v2_mount = next((m for m, kind, _ in mounts if kind == "cgroup2"), None)
    if v2_mount is None:
        missing.append("no cgroup v2 mount (no cgroup.kill): a run's processes are killed by its PID "
                       "namespace's end and a scan of its uid, repeated until none is left")
    else:
        v2, v2_controllers = _v2_base(Path(v2_mount), own.get("", "/"), missing)
    kill = v2 is not None and (v2 / "cgroup.kill").exists()
    v1: dict[str, Path] = {}
    for name in V1_CONTROLLERS:
        if v2_controllers and name in v2_controllers:
            continue
        mount = next((m for m, kind, opts in mounts if kind == "cgroup" and name in opts.split(",")), None)
        if mount is None:
            continue
        base = Path(mount) / own.get(name, "/").lstrip("/") / SANDBOX_GROUP
        try:
            base.mkdir(exist_ok=True)
        except OSError:
            continue
        if _writable(base):
            v1[name] = base
    found = Support(v2, frozenset(v2_controllers or ()), v1)
    found.release()  # made again by the first run (ensure_bases)
    lacking = [n for n in V1_CONTROLLERS if n not in v1 and n not in (v2_controllers or ())]
    if lacking:
        missing.append(f"no {', '.join(lacking)} controller this process may use: rlimits only for "
                       + ("them" if len(lacking) > 1 else "it"))
    return Support(v2, frozenset(v2_controllers or ()), v1, tuple(missing), kill)


def _v2_base(mount: Path, own: str, missing: list[str]) -> tuple[Path | None, set[str]]:
    """The sandbox's base group in v2: at the root (root), else under this process's own group when
    it is delegated to this user (systemd's user@.service); with the controllers it can enable."""
    for parent in (mount, mount / own.lstrip("/")):
        base = parent / SANDBOX_GROUP
        try:
            base.mkdir(exist_ok=True)
        except OSError:
            continue
        if not _writable(base):
            continue
        wanted = set(_read(base / "cgroup.controllers").split()) & set(V1_CONTROLLERS)
        for name in sorted(wanted):
            try:
                (base / "cgroup.subtree_control").write_text(f"+{name}")
            except OSError:
                wanted.discard(name)
        if not (base / "cgroup.kill").exists():
            missing.append("cgroup v2 without cgroup.kill (Linux < 5.14)")
        if not wanted:
            missing.append(f"cgroup v2 at {mount} enables none of memory, pids, cpu for this process")
        return base, wanted
    missing.append(f"cgroup v2 at {mount} is not writable by this process (not root, no delegated group)")
    return None, set()


def release_if_used() -> None:
    """Where this process uses the sandbox's groups (a Core or Platform at its start and stop): the
    groups of creators that died removed (`sweep`), then the base groups where empty."""
    if support.cache_info().currsize:
        sweep()
        support().release()


_serial = itertools.count(1)


class RunGroup:
    """One run's group in every hierarchy `support()` found; `None` paths when there is none."""

    def __init__(self, name: str, paths: list[Path], v2: Path | None):
        self.name, self.paths, self.v2 = name, paths, v2

    @classmethod
    def create(cls, limits, nice: int = 0, sup: Support | None = None) -> "RunGroup | None":
        """A new group with `limits` (agents/process.py Limits: memory_bytes, processes, cpu_cores)."""
        sup = sup or support()
        if not sup.any():
            return None
        name = f"{os.getpid()}-{next(_serial)}"
        paths: list[Path] = []
        v2 = None
        try:
            sup.ensure_bases()
            if sup.v2 is not None:
                v2 = sup.v2 / name
                v2.mkdir()
                paths.append(v2)
                _limit_v2(v2, limits, sup.v2_controllers)
            for ctrl, base in sup.v1.items():
                path = base / name
                path.mkdir()
                paths.append(path)
                _limit_v1(ctrl, path, limits)
        except OSError:
            cls(name, paths, v2).remove()
            raise
        group = cls(name, paths, v2)
        group.set_nice(nice)
        return group

    def procs_files(self) -> list[str]:
        return [str(p / "cgroup.procs") for p in self.paths]

    def set_nice(self, nice: int) -> None:
        """The group's CPU weight as a session at `nice` would have (best effort)."""
        weight = NICE_WEIGHT[max(0, min(19, nice))]
        for p in self.paths:
            for name, value in (("cpu.weight", max(1, round(weight * 100 / 1024))), ("cpu.shares", weight)):
                if (p / name).exists():
                    try:
                        (p / name).write_text(str(value))
                    except OSError:
                        pass

    def pids(self) -> list[int]:
        out: set[int] = set()
        for p in self.paths:
            out.update(int(x) for x in _read(p / "cgroup.procs").split())
        return sorted(out)

    def kill(self, timeout: float = 2.0) -> bool:
        """Every process of the group killed: `cgroup.kill`, else SIGKILL to each listed, again until
        none is left (a fork between a read and the kills is caught by the next read). True when empty."""
        if self.v2 is not None and (self.v2 / "cgroup.kill").exists():
            try:
                (self.v2 / "cgroup.kill").write_text("1")
            except OSError:
                pass
        deadline = time.monotonic() + timeout
        while True:
            pids = self.pids()
            if not pids:
                return True
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            if time.monotonic() > deadline:
                return False
            time.sleep(0.005)

    def remove(self) -> bool:
        """The group's directories gone (False while a process is still being torn down in it)."""
        done = True
        for p in reversed(self.paths):
            try:
                p.rmdir()
            except FileNotFoundError:
                pass
            except OSError as e:
                done = False
                if e.errno not in (errno.EBUSY, errno.ENOTEMPTY):
                    raise
        return done

    def refusals(self) -> dict[str, int]:
        """What the kernel refused the group, where it counts: {"oom_kill": n, "pids_max": n}."""
        out: dict[str, int] = {}
        for p in self.paths:  # v2 memory.events / v1 memory.oom_control; pids.events in both
            for name, key, as_ in (("memory.events", "oom_kill", "oom_kill"), ("memory.oom_control", "oom_kill", "oom_kill"),
                                   ("pids.events", "max", "pids_max")):
                for line in _read(p / name).splitlines():
                    k, _, v = line.partition(" ")
                    if k == key and v.isdigit() and int(v):
                        out[as_] = max(out.get(as_, 0), int(v))
        return out


def _limit_v2(path: Path, limits, controllers) -> None:
    if "memory" in controllers and limits.memory_bytes:
        (path / "memory.max").write_text(str(limits.memory_bytes))
        (path / "memory.swap.max").exists() and (path / "memory.swap.max").write_text("0")
    if "pids" in controllers and limits.processes:
        (path / "pids.max").write_text(str(limits.processes + PIDS_SLACK))
    if "cpu" in controllers and limits.cpu_cores:
        (path / "cpu.max").write_text(f"{int(limits.cpu_cores * CPU_PERIOD_US)} {CPU_PERIOD_US}")


def _limit_v1(ctrl: str, path: Path, limits) -> None:
    if ctrl == "memory" and limits.memory_bytes:
        (path / "memory.limit_in_bytes").write_text(str(limits.memory_bytes))
    elif ctrl == "pids" and limits.processes:
        (path / "pids.max").write_text(str(limits.processes + PIDS_SLACK))
    elif ctrl == "cpu" and limits.cpu_cores:
        (path / "cpu.cfs_period_us").write_text(str(CPU_PERIOD_US))
        (path / "cpu.cfs_quota_us").write_text(str(int(limits.cpu_cores * CPU_PERIOD_US)))


def sweep(sup: Support | None = None) -> list[str]:
    """Groups left by processes that are gone (a Core killed before it removed its runs'): their
    processes killed, the groups removed. Names are `<creator pid>-<n>`."""
    sup = sup or support()
    bases = sup.bases()
    gone = []
    for base in bases:
        try:
            entries = list(base.iterdir())
        except OSError:
            continue
        for entry in entries:
            creator = entry.name.split("-")[0]
            if not entry.is_dir() or not creator.isdigit() or _alive(int(creator)):
                continue
            group = RunGroup(entry.name, [entry], entry if base == sup.v2 else None)
            group.kill(timeout=1.0)
            if group.remove():
                gone.append(str(entry))
    return gone


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
        return True
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
