"""CPU seconds and memory of a run's processes by kind, sampled from /proc (Linux).

Every descendant of this process (and any process named to `ProcessKinds`) is sampled each
`period` s in a thread: its CPU time (utime + stime, all threads) and, every `mem_every` samples,
its proportional set size (Pss: pages shared by forked workers counted once among them). A
process is classified by the nearest named ancestor (or itself): `kinds.named` maps a pid to its
kind, and under a named process an `agents.runtime` process (a Dynamic or Cloud Agent, a warm
worker) takes that ancestor's `runtime_kind`. What a process spends between its last sample and
its exit is lost (at most `period` s of it; agents are mostly idle when they end).

    sampler = ProcessSampler(kinds).start()
    before = sampler.mark()
    ...                                   # the work measured
    usage = sampler.since(before)         # {"cpu_s": {kind: s}, "pss_mb_peak": {kind: MB}, ...}
    sampler.stop()
"""
from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

CLK_TCK = os.sysconf("SC_CLK_TCK")
RUNTIME = b"agents.runtime"


@dataclass
class ProcessKinds:
    """How processes are named: `named` pid -> kind (the root of the tree first); `runtime_kind`
    named kind -> the kind of an `agents.runtime` process below it (e.g. "platform" -> "cloud")."""
    root: int
    root_kind: str
    named: dict[int, str] = field(default_factory=dict)
    runtime_kind: dict[str, str] = field(default_factory=dict)

    version: int = 0  # changes with every name given: kinds seen before are looked at again

    def name(self, pid: int, kind: str) -> None:
        self.named[pid] = kind
        self.version += 1


def read_stat(pid: int) -> tuple[int, float, int] | None:
    """(ppid, CPU seconds, start time in ticks) of a live process; None if it is gone."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_bytes()
    except OSError:
        return None
    rest = raw[raw.rindex(b")") + 2:].split()  # the command name may hold spaces and parentheses
    return int(rest[1]), (int(rest[11]) + int(rest[12])) / CLK_TCK, int(rest[19])


def read_pss_kb(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_bytes().splitlines():
            if line.startswith(b"Pss:"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return 0


def read_cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


class ProcessSampler:
    def __init__(self, kinds: ProcessKinds, period: float = 0.5, mem_every: int = 10):
        self.kinds, self.period, self.mem_every = kinds, period, mem_every
        # a process is (pid, start time): a pid may be reused within a long run
        self.cpu: dict[tuple[int, int], float] = {}  # last CPU seconds seen (kept after its exit)
        self.kind_of: dict[tuple[int, int], str] = {}  # kind, fixed at first sight
        self.samples: list[tuple[float, dict[str, float]]] = []  # (time, Pss MB by kind)
        self.alive: dict[str, int] = {}  # kind -> processes alive at the last sample
        self.peak_alive: dict[str, int] = {}
        self.fds_peak: dict[str, int] = {}  # open descriptors of the named processes, by kind (since the mark)
        self.sampling_cpu_s = 0.0  # this thread's own cost
        self._version = kinds.version
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- classification ------------------------------------------------------------------
    def _classify(self, pid: int, ppids: dict[int, int]) -> str | None:
        """The kind of `pid`, or None if it is not in the measured tree."""
        k = self.kinds
        chain, p = [], pid
        while p > 1 and p not in k.named and p != k.root:
            chain.append(p)
            p = ppids.get(p, 0)
        if p <= 1:
            return None
        top = k.root_kind if p == k.root else k.named[p]
        if chain and top in k.runtime_kind and any(RUNTIME in read_cmdline(c) for c in chain):
            return k.runtime_kind[top]
        return top

    # -- sampling ------------------------------------------------------------------------
    def sample(self, with_memory: bool = False) -> None:
        stats: dict[int, tuple[int, float, int]] = {}
        for entry in os.scandir("/proc"):
            if entry.name.isdigit():
                s = read_stat(int(entry.name))
                if s is not None:
                    stats[int(entry.name)] = s
        ppids = {pid: s[0] for pid, s in stats.items()}
        pss: dict[str, float] = {}
        alive: dict[str, int] = {}
        with self._lock:
            before: dict[tuple[int, int], str] = {}
            if self._version != self.kinds.version:  # a process named since it was first seen
                self._version = self.kinds.version
                before, self.kind_of = self.kind_of, {k: v for k, v in self.kind_of.items() if k[0] not in stats}
            for pid, (_, cpu, started) in stats.items():
                key = (pid, started)
                kind = self.kind_of.get(key)
                if kind is None:
                    # a process seen before keeps its kind where it can no longer be placed (its
                    # parent gone, it was reparented out of the measured tree)
                    kind = self._classify(pid, ppids) or before.get(key)
                    if kind is None:
                        continue
                    self.kind_of[key] = kind
                self.cpu[key] = cpu
                alive[kind] = alive.get(kind, 0) + 1
                if with_memory:
                    pss[kind] = pss.get(kind, 0.0) + read_pss_kb(pid) / 1024
            self.alive = alive
            for pid, kind in list(self.kinds.named.items()) + [(self.kinds.root, self.kinds.root_kind)]:
                try:
                    self.fds_peak[kind] = max(self.fds_peak.get(kind, 0), len(os.listdir(f"/proc/{pid}/fd")))
                except OSError:
                    pass
            for kind, count in alive.items():
                self.peak_alive[kind] = max(self.peak_alive.get(kind, 0), count)
            if with_memory:
                self.samples.append((time.time(), pss))

    def _loop(self) -> None:
        i = 0
        t0 = time.thread_time()
        while not self._stop.wait(self.period):
            self.sample(with_memory=i % self.mem_every == 0)
            i += 1
            self.sampling_cpu_s = time.thread_time() - t0

    def start(self) -> "ProcessSampler":
        self.sample(with_memory=True)
        self._thread = threading.Thread(target=self._loop, name="proc-sampler", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)

    # -- reading -------------------------------------------------------------------------
    def mark(self) -> tuple[float, dict[tuple[int, int], float]]:
        self.sample(with_memory=True)
        with self._lock:
            self.peak_alive = dict(self.alive)
            self.fds_peak = {}
            return time.time(), dict(self.cpu)

    def since(self, mark: tuple[float, dict[tuple[int, int], float]]) -> dict:
        """CPU seconds by kind since `mark` (processes started since count whole), the peak Pss by
        kind and the peak of all kinds together over the samples since, the most processes of each
        kind alive at once since, the most descriptors a named process of each kind held open, the
        wall time."""
        self.sample(with_memory=True)
        t_mark, before = mark
        with self._lock:
            cpu: dict[str, float] = {}
            for key, s in self.cpu.items():
                kind = self.kind_of[key]  # every process in self.cpu keeps a kind (sample)
                cpu[kind] = cpu.get(kind, 0.0) + s - before.get(key, 0.0)
            window = [m for t, m in self.samples if t >= t_mark]
        peak = {k: max(m.get(k, 0.0) for m in window) for k in {k for m in window for k in m}}
        return {"wall_s": time.time() - t_mark, "cpu_s": {k: round(v, 2) for k, v in sorted(cpu.items())},
                "pss_mb_peak": {k: round(v, 1) for k, v in sorted(peak.items())},
                "pss_mb_peak_total": round(max((sum(m.values()) for m in window), default=0.0), 1),
                "processes_peak": dict(sorted(self.peak_alive.items())),
                "fds_peak": dict(sorted(self.fds_peak.items()))}



def mem_available_mb() -> float:
    """The kernel's estimate of memory available without swapping (MemAvailable), MB."""
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemAvailable:"):
            return int(line.split()[1]) / 1024
    return float("inf")
