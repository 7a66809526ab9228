"""The resource limits of a RApp's process (rlimits, and the CPU quota of its control group), which
the process applies to itself once confined (agents/sandbox.py confine); agents/process.py
passes them on."""
from __future__ import annotations

import resource
from dataclasses import dataclass


@dataclass(frozen=True)
class Limits:
    cpu_seconds: int | None = 600
    memory_bytes: int | None = 2 * 1024**3
    open_files: int | None = 1024
    processes: int | None = 128  # tasks (threads count); only under a sandbox uid of its own
    file_size_bytes: int | None = 256 * 1024**2
    cpu_cores: float | None = 1.0  # the run's control group's CPU quota, where there is one

    def apply(self, own_uid: bool = True) -> None:  # by the RApp process itself (agents/sandbox.py confine)
        limits = [(resource.RLIMIT_CPU, self.cpu_seconds, 5), (resource.RLIMIT_AS, self.memory_bytes, 0),
                  (resource.RLIMIT_NOFILE, self.open_files, 0),
                  (resource.RLIMIT_FSIZE, self.file_size_bytes, 0)]
        if own_uid:  # RLIMIT_NPROC counts every process of the uid: only meaningful for a fresh one
            limits.append((resource.RLIMIT_NPROC, self.processes, 0))
        for which, value, slack in limits:
            if value:
                resource.setrlimit(which, (value, value + slack))
