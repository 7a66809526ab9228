"""Is a silent Dynamic Agent hung, or only late? (the Core's heartbeat judgment, s8)

A Dynamic Agent beats every 0.25 s from its event loop; the Core ends it after 1.5 s of silence.
On a loaded machine (a fleet of robots on two cores) a live agent's beats can be late for seconds:
its process waits for a CPU, or its beats wait in the server or in the Core's own backlog. From
the second missed beat on, the Core looks at the main thread of the agent's process (the one that
runs its loop; Linux /proc, readable by the Core that started it) at every check, and judges:

  seen waiting in epoll   its loop turns: the beats are late on the way, not its fault
  runnable, no CPU        it waits for a CPU (at most two clock ticks used since the first look)
  anything else           hung: running without beating (a spin), asleep outside its loop
                          (time.sleep, a lock, a blocking read), stopped, or gone

A late agent gets at most `GRACE_S` of silence in all; then it is hung whatever its state.
A loop that spins while another thread of its process contends for the GIL, or polls with
time.sleep(), can look alive at one look: the grace bounds what that costs.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

MARK_AFTER_S = 0.5  # two beats missed: the silence's first look at the process
GRACE_S = 6.0  # the longest silence a late (not hung) agent is allowed
MIN_WINDOW_S = 0.3  # a shorter window proves nothing (the kernel counts CPU in 10 ms ticks)
LOOP_WAITS = ("do_epoll_wait", "ep_poll", "do_sys_poll", "do_select", "core_sys_select")
_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class ThreadSample:
    """The main thread of a process at one moment: its state letter, the kernel function it
    sleeps in, and the CPU time it has used so far."""

    state: str
    wchan: str
    cpu_s: float


@dataclass
class SilenceWatch:
    """The looks at a silent agent's main thread: the first one (taken at `at`, monotonic) and
    whether any showed its loop waiting for events."""

    at: float
    first: ThreadSample | None
    loop_seen_waiting: bool = False
    noted: bool = False  # the Core has recorded that it waits

    def __post_init__(self) -> None:
        self.look(self.first)

    def look(self, sample: ThreadSample | None) -> None:
        if sample is not None and sample.state == "S" and sample.wchan in LOOP_WAITS:
            self.loop_seen_waiting = True

    def late_not_hung(self, now: ThreadSample | None, at: float) -> str | None:
        """Why the silence is not (yet) a hang, given the latest look `now` (taken at `at`,
        monotonic, and passed to `look` first); None when it is one."""
        if now is None:
            return None
        if self.loop_seen_waiting:
            return "its loop waits for events"
        if now.state == "R" and self.first is not None and at - self.at >= MIN_WINDOW_S \
                and now.cpu_s - self.first.cpu_s <= 2 * _TICK_S:
            return "it waits for a CPU"
        return None


def sample_main_thread(pid: int) -> ThreadSample | None:
    """None when the process is gone or its /proc entry cannot be read."""
    task = Path(f"/proc/{pid}/task/{pid}")
    try:
        stat = (task / "stat").read_text()
        wchan = (task / "wchan").read_text().strip()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[1].split()  # after "pid (comm)": state is field 3, utime 14, stime 15
    return ThreadSample(fields[0], wchan, (int(fields[11]) + int(fields[12])) * _TICK_S)
