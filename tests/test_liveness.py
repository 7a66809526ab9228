"""agents/liveness.py on real processes: a spinning loop and a loop blocked in time.sleep are hung;
an idle asyncio loop, and one that shares its CPU with a busy process at the lowest priority, are
only late; so is a runnable thread that got no CPU (the rule, on samples); a process that is gone
is hung."""
from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from agents.core_agent import CoreAgent, DynamicSession
from agents.core_strategies import Strategies
from agents.liveness import SilenceWatch, ThreadSample, sample_main_thread

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
    watch = SilenceWatch(time.monotonic(), sample_main_thread(pid))
    for _ in range(looks):
        time.sleep(window_s / looks)
        sample = sample_main_thread(pid)
        watch.look(sample)
    return watch.late_not_hung(sample, time.monotonic())


@pytest.mark.parametrize("name, expect", [
    ("spin", {None}), ("sleep", {None}), ("loop", {"its loop waits for events"}),
    # woken every 10 ms, so on a loaded machine it may be caught runnable without a CPU: never a loop
    ("poll", {None, "it waits for a CPU"})])
def test_a_silent_process_is_judged_by_its_main_thread(name, expect):
    proc = start(PROGRAMS[name])
    try:
        assert judge(proc.pid) in expect
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
        # seen waiting in its loop between the hog's slices, or (on a loaded machine) runnable without CPU
        assert judge(loop.pid) in ("its loop waits for events", "it waits for a CPU")
    finally:
        for p in (loop, hog):
            p.kill()
            p.wait()


@pytest.mark.parametrize("cpu_used, window, expect", [
    (0.0, 1.0, "it waits for a CPU"),  # runnable all along, never run
    (0.02, 1.0, "it waits for a CPU"),  # two clock ticks: the scheduler's noise
    (0.3, 1.0, None),  # it had the CPU and did not beat: a spin
    (0.0, 0.2, None),  # too short a window to tell
])
def test_a_runnable_thread_is_late_only_without_cpu(cpu_used, window, expect):
    """The rule on samples (a real thread's runnable-without-CPU moment cannot be made on demand)."""
    first = ThreadSample("R", "0", 5.0)
    watch = SilenceWatch(100.0, first)
    now = ThreadSample("R", "0", 5.0 + cpu_used)
    watch.look(now)
    assert watch.late_not_hung(now, 100.0 + window) == expect


def test_a_process_that_is_gone_is_hung():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    watch = SilenceWatch(time.monotonic() - 1.0, sample_main_thread(proc.pid))
    proc.wait()
    assert sample_main_thread(proc.pid) is None
    assert watch.late_not_hung(None, time.monotonic()) is None


async def test_silence_before_the_core_watches_is_not_a_hang():
    """The Core enters s8 late (its loop held up by the hand-over): the beats it has not read yet
    are no evidence. The Dynamic Agent's last beat is 5 s old when serving begins; it ends by itself
    0.5 s later, not as hung."""
    session = DynamicSession(jid="dyn@localhost", rapp="r", version="1", manifest=SimpleNamespace(time_limit_s=60),
                             workdir=Path("."), state="Working")
    session.last_beat -= 5.0

    def end(s, reason):
        s.end_reason = reason
        s.ended.set()

    core = SimpleNamespace(dynamic=session, robot_commands=SimpleNamespace(estop_reason=None),
                           _late_not_hung=lambda *a: False, _end=end,
                           strategies=SimpleNamespace(pause_allowance_s=Strategies.pause_allowance_s))
    asyncio.get_running_loop().call_later(0.5, end, session, "finished")
    assert await CoreAgent.serve_until_done(core) == "finished"
