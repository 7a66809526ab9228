"""CPU priority of agent processes: per thread, and per session (Linux's autogroup).

Linux keeps a nice value per thread, and, with `kernel.sched_autogroup_enabled` (the default of
most distributions), schedules each session as one group: groups share the CPU by the group's own
nice value, and a thread's nice only counts against threads of its own session. Every RApp process
leads a session of its own (start_new_session), so lowering its threads' nice alone changed nothing
against the Platform or another RApp: measured, a busy loop at nice 10 in its own session took
half of a core from one at nice 0, as at nice 0; with its group at nice 10 too, a tenth.

Writing a group's nice (/proc/PID/autogroup) needs no privilege for values >= 0, but unprivileged
writes are limited to one every 100 ms for the whole machine (EAGAIN); root's are not. A process in
a CPU cgroup other than the root one (a systemd service, a container) is not scheduled by autogroup:
there the threads' nice values, set too, are what counts.
"""
from __future__ import annotations

import errno
import os
import resource
import time

RATE_LIMIT_S = 0.11  # an unprivileged writer's wait between group writes (the kernel's 100 ms)


def each_thread(pid: int, call) -> None:
    """`call(tid)` for every thread of `pid`: Linux keeps a priority and a scheduling policy per
    thread (a warm worker's BLAS threads started at its low priority). A thread that ends meanwhile
    is skipped."""
    try:
        tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        tids = [pid]
    for tid in tids:
        try:
            call(tid)
        except ProcessLookupError:
            pass


def set_group_nice(pid: int, nice: int, retry_s: float = 0.0) -> bool:
    """The nice value of `pid`'s autogroup, where `pid` leads its session (a process that does not
    would change its parent's group). False only when the write was refused for the rate limit
    for `retry_s` seconds (blocking: off the event loop only); True when done, not needed, or not
    possible here (no autogroup)."""
    deadline = time.monotonic() + retry_s
    while not _write_group_nice(pid, nice):
        if time.monotonic() + RATE_LIMIT_S > deadline:
            return False
        time.sleep(RATE_LIMIT_S)
    return True


def _write_group_nice(pid: int, nice: int) -> bool:
    nice = max(0, min(19, nice))  # below 0 needs a privilege the callers do not rely on
    path = f"/proc/{pid}/autogroup"
    try:
        if os.getsid(pid) != pid:
            return True
        with open(path) as f:  # "/autogroup-123 nice 10"
            if int(f.read().split()[-1]) == nice:
                return True
        with open(path, "w") as f:
            f.write(str(nice))
        return True
    except OSError as e:
        return e.errno != errno.EAGAIN  # ENOENT (no autogroup), ESRCH (gone), EACCES: nothing to retry
    except (ValueError, IndexError):
        return True


def set_priority(pid: int, nice: int, retry_s: float = 0.0) -> bool:
    """Every thread of `pid` to `nice`, and its session's group (set_group_nice, whose result it
    returns); PermissionError where raising the threads' needs a privilege we lack."""
    each_thread(pid, lambda tid: os.setpriority(os.PRIO_PROCESS, tid, nice))
    return set_group_nice(pid, nice, retry_s)


def may_raise_priority() -> bool:
    """Whether this process can give a child it lowered its own priority back (root, or an
    RLIMIT_NICE that allows it)."""
    if os.geteuid() == 0:
        return True
    own = os.getpriority(os.PRIO_PROCESS, 0)
    return 20 - resource.getrlimit(resource.RLIMIT_NICE)[0] <= own
