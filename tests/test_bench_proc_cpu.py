"""bench/proc_cpu.py: the fleet benchmark's CPU and memory by process kind, read from /proc."""
from __future__ import annotations

import os
import subprocess
import sys
import time

from bench.proc_cpu import ProcessKinds, ProcessSampler, mem_available_mb, read_stat

BUSY = "import time\nt = time.process_time()\nwhile time.process_time() - t < {s}: pass\ntime.sleep(30)"
RUNTIME_ARGV0 = "python -m agents.runtime"  # what the classification looks for in a command line
# a process that starts an agents.runtime child (as the Platform starts a Cloud Agent), then sleeps
# (the name built at run time: its own command line must not hold it)
PARENT = ("import subprocess, sys, time\n"
          "subprocess.Popen(['python -m agents.' + 'runtime', '-c', 'import time; time.sleep(30)'], executable=sys.executable)\n"
          "time.sleep(30)")


def wait_cpu(pid: int, seconds: float) -> None:
    deadline = time.monotonic() + 30
    while read_stat(pid)[1] < seconds and time.monotonic() < deadline:
        time.sleep(0.01)


def wait_for_children(pid: int, n: int) -> None:
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        kids = open(f"/proc/{pid}/task/{pid}/children").read().split()
        if len(kids) >= n and all(RUNTIME_ARGV0.encode() in open(f"/proc/{k}/cmdline", "rb").read() for k in kids):
            return
        time.sleep(0.02)
    raise AssertionError(f"{pid} has not started {n} runtime children")


def test_cpu_is_counted_from_the_mark_by_the_named_kind():
    """A named process's CPU goes to its kind, from the mark on; an unnamed child of the root is the
    root's kind; memory (Pss) and the most processes alive at once are reported per kind."""
    platform = subprocess.Popen([sys.executable, "-c", BUSY.format(s=0.6)])
    plain = subprocess.Popen([sys.executable, "-c", BUSY.format(s=0.2)])
    kinds = ProcessKinds(os.getpid(), "cores")
    kinds.name(platform.pid, "platform")
    sampler = ProcessSampler(kinds, period=0.1, mem_every=1)
    try:
        sampler.start()
        wait_cpu(platform.pid, 0.3)  # the busy loop half done (however loaded the machine)
        at_mark = read_stat(platform.pid)[1]
        mark = sampler.mark()
        wait_cpu(platform.pid, 0.6)  # then it sleeps: its CPU stays where it is
        after = read_stat(platform.pid)[1] - at_mark
        deadline = time.monotonic() + 10  # the sampler's next samples (its thread may wait for a CPU)
        usage = sampler.since(mark)
        while usage["cpu_s"]["platform"] < after - 0.05 and time.monotonic() < deadline:
            time.sleep(0.1)
            usage = sampler.since(mark)
        assert after - 0.05 <= usage["cpu_s"]["platform"] <= after + 0.05  # only what it spent after the mark
        assert usage["pss_mb_peak"]["platform"] > 1 and usage["pss_mb_peak_total"] > usage["pss_mb_peak"]["platform"]
        assert usage["processes_peak"]["platform"] == 1
    finally:
        sampler.stop()
        for p in (platform, plain):
            p.kill()
            p.wait()


def test_a_runtime_takes_the_runtime_kind_of_the_named_process_above_it():
    """An agents.runtime process under the Platform is a Cloud Agent, one under the root (the Cores'
    process) a Dynamic Agent; a process named after it was first seen is classified again."""
    platform = subprocess.Popen([sys.executable, "-c", PARENT])
    dynamic = subprocess.Popen([RUNTIME_ARGV0, "-c", "import time; time.sleep(30)"], executable=sys.executable)
    kinds = ProcessKinds(os.getpid(), "cores", runtime_kind={"cores": "dynamic", "platform": "cloud"})
    sampler = ProcessSampler(kinds)
    try:
        wait_for_children(platform.pid, 1)
        sampler.sample()
        assert sampler.alive.get("dynamic") == 2 and "cloud" not in sampler.alive  # both under the root
        kinds.name(platform.pid, "platform")
        sampler.sample()
        assert (sampler.alive.get("platform"), sampler.alive.get("cloud"), sampler.alive.get("dynamic")) == (1, 1, 1)
    finally:
        for p in (platform, dynamic):
            os.system(f"pkill -KILL -P {p.pid}")  # the platform stand-in's child (by its parent's pid)
            p.kill()
            p.wait()


def test_memory_available_is_read():
    assert 0 < mem_available_mb() < float("inf")


def test_a_process_reparented_out_of_the_tree_keeps_its_kind():
    """A process whose parent died is reparented (to init): seen again after a process was named,
    it can no longer be placed, and keeps the kind it had (its CPU is still counted)."""
    orphan_maker = subprocess.Popen([sys.executable, "-c",
                                     "import subprocess, sys; p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(30)']); print(p.pid, flush=True)"],
                                    stdout=subprocess.PIPE, text=True)
    kinds = ProcessKinds(os.getpid(), "cores")
    sampler = ProcessSampler(kinds)
    orphan = int(orphan_maker.stdout.readline())
    try:
        sampler.sample()  # the child seen under its parent: "cores"
        mark = sampler.mark()
        orphan_maker.wait(10)  # its parent exits: the child is reparented out of this tree
        deadline = time.monotonic() + 5
        while read_stat(orphan)[0] == orphan_maker.pid and time.monotonic() < deadline:
            time.sleep(0.01)
        kinds.name(orphan_maker.pid, "gone")  # any naming makes the sampler look at every process again
        usage = sampler.since(mark)
        assert "cores" in usage["cpu_s"] and sampler.alive.get("cores", 0) >= 2  # the orphan and this process
    finally:
        os.kill(orphan, 9)
