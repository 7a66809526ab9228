"""A benchmark's children end with it (bench/common.py spawn, end_group): a killed `rapp bench`
had left its hazard run's processes running."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from bench.common import end_group, spawn

from .test_run_watchdog import _alive

ROOT = Path(__file__).resolve().parent.parent
# a child that starts a grandchild in its session; both ignore SIGTERM, as a slow agent might
STUBBORN = ("import signal, subprocess, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
            "g = subprocess.Popen([sys.executable, '-c', 'import signal, time; "
            "signal.signal(signal.SIGTERM, signal.SIG_IGN); time.sleep(300)']); "
            "print(g.pid, flush=True); time.sleep(300)")


def _gone_within(pid: int, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not _alive(pid)


def test_end_group_ends_the_child_and_what_it_started():
    proc = spawn([sys.executable, "-c", STUBBORN], stdout=subprocess.PIPE, text=True)
    grandchild = int(proc.stdout.readline())
    assert _alive(grandchild)
    t0 = time.monotonic()
    end_group(proc, grace_s=0.5)
    assert proc.poll() is not None and _gone_within(grandchild, 2.0)
    assert time.monotonic() - t0 < 5.0


def test_a_killed_bench_takes_its_child_along():
    bench = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from bench.common import spawn; "
        "c = spawn([sys.executable, '-c', 'import time; time.sleep(300)']); print(c.pid, flush=True); "
        "time.sleep(300)")], cwd=ROOT, stdout=subprocess.PIPE, text=True, start_new_session=True)
    child = int(bench.stdout.readline())
    try:
        assert _alive(child)
        os.kill(bench.pid, signal.SIGKILL)  # nothing of the bench runs after this
        bench.wait()
        assert _gone_within(child, 5.0), "the bench's child outlived it"
    finally:
        for pid in (bench.pid, child):
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
