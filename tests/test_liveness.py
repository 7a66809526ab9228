"""agents/liveness.py on real processes: a spinning loop and a loop blocked in time.sleep are hung;
an idle asyncio loop, and one that shares its CPU with a busy process at the lowest priority, are
only late; so is a process that could not run at all (stopped here, then let go: the looks see it
runnable without CPU); a process that is gone is hung."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from agents.liveness import SilenceWatch, sample_main_thread

LOOP = "import asyncio\nasync def m():\n    while True:\n        await asyncio.sleep(0.25)\nasyncio.run(m())"
PROGRAMS = {
    "spin": "while True: pass",
    "sleep": "import time; time.sleep(100)",
    "poll": "import time\nwhile True: time.sleep(0.01)",  # wakes, but a loop it ran would not turn
    "loop": LOOP,
}


def start(code: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", code])
    time.sleep(0.5)  # the interpreter started
    return proc


def judge(pid: int, window_s: float = 1.0, looks: int = 10) -> str | None:
    """As the Core does: a first look, more every window_s / looks, the verdict at the last."""
    watch = SilenceWatch(0, time.monotonic(), sample_main_thread(pid))
    for _ in range(looks):
        time.sleep(window_s / looks)
        sample = sample_main_thread(pid)
        watch.look(sample)
    return watch.late_not_hung(sample, time.monotonic())


@pytest.mark.parametrize("name, expect", [
    ("spin", None), ("sleep", None), ("poll", None), ("loop", "its loop waits for events")])
def test_a_silent_process_is_judged_by_its_main_thread(name, expect):
    proc = start(PROGRAMS[name])
    try:
        assert judge(proc.pid) == expect
    finally:
        proc.kill()
        proc.wait()


def test_a_loop_behind_a_busy_process_on_its_cpu_is_late():
    cpu = min(os.sched_getaffinity(0))
    loop, hog = start(LOOP), start(PROGRAMS["spin"])
    try:
        for p in (loop, hog):
            os.sched_setaffinity(p.pid, {cpu})
        os.sched_setscheduler(loop.pid, os.SCHED_IDLE, os.sched_param(0))  # runs only when the CPU is free
        assert judge(loop.pid) == "its loop waits for events"
    finally:
        for p in (loop, hog):
            p.kill()
            p.wait()


def test_a_runnable_process_without_cpu_is_late():
    """R without CPU since the first look: a stopped loop woken as the verdict is taken stands
    for one the scheduler has not run yet."""
    proc = start(LOOP)
    try:
        os.kill(proc.pid, signal.SIGSTOP)
        time.sleep(0.3)  # its timer expires while stopped: runnable the moment it is let go
        watch = SilenceWatch(0, time.monotonic(), sample_main_thread(proc.pid))
        time.sleep(0.5)
        assert watch.late_not_hung(sample_main_thread(proc.pid), time.monotonic()) is None  # stopped: hung
        os.kill(proc.pid, signal.SIGCONT)
        looks = [sample_main_thread(proc.pid) for _ in range(200)]
        running = next((s for s in looks if s.state == "R"), None)
        if running is None:
            pytest.skip("the woken loop was never seen runnable")
        assert watch.late_not_hung(running, time.monotonic()) == "it waits for a CPU"
    finally:
        proc.kill()
        proc.wait()


def test_a_process_that_is_gone_is_hung():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    watch = SilenceWatch(0, time.monotonic() - 1.0, sample_main_thread(proc.pid))
    proc.wait()
    assert sample_main_thread(proc.pid) is None
    assert watch.late_not_hung(None, time.monotonic()) is None
