"""A lowered priority must count against other sessions: every RApp process leads a session of its
own, and with Linux's autogroup a thread's nice value alone only counts inside its session."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from agents.priority import set_group_nice, set_priority

BUSY = "while True: pass"


def group_nice(pid: int) -> int | None:
    """None for a process in the root group (empty file): a session that began before autogroup
    took over, e.g. init's, where a CI runner may start the tests."""
    words = Path(f"/proc/{pid}/autogroup").read_text().split()
    return int(words[-1]) if words else None


def cpu_ticks(pid: int) -> int:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])


@pytest.fixture
def busy():
    if not Path("/proc/self/autogroup").exists():
        pytest.skip("this kernel schedules without autogroups")
    procs = []

    def start(new_session: bool = True) -> subprocess.Popen:
        p = subprocess.Popen([sys.executable, "-c", BUSY], start_new_session=new_session)
        procs.append(p)
        os.sched_setaffinity(p.pid, {min(os.sched_getaffinity(0))})  # both on one CPU: they compete
        return p

    yield start
    for p in procs:
        p.kill()
        p.wait()


def test_a_lowered_session_leader_yields_the_cpu_to_another_session(busy):
    normal, low = busy(), busy()
    assert set_priority(low.pid, 10)
    assert group_nice(low.pid) == 10 and os.getpriority(os.PRIO_PROCESS, low.pid) == 10
    time.sleep(0.2)
    a, b = cpu_ticks(normal.pid), cpu_ticks(low.pid)
    time.sleep(1.5)
    a, b = cpu_ticks(normal.pid) - a, cpu_ticks(low.pid) - b
    # weights 1024 against 110: about 9 to 1; the threads' nice alone gave 1 to 1
    assert b < 0.4 * a, (a, b)


SPAWNS_A_CHILD = (
    "import subprocess, sys\n"
    "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
    "print(child.pid, flush=True)\n"
    "child.wait()\n"
)


def test_a_process_in_its_parents_session_leaves_the_group_alone(busy):
    # the parent leads a session of its own, so its group is a real one wherever the tests run
    leader = subprocess.Popen([sys.executable, "-c", SPAWNS_A_CHILD], stdout=subprocess.PIPE,
                              start_new_session=True, text=True)
    try:
        child = int(leader.stdout.readline())
        assert os.getsid(child) == leader.pid != child
        before = group_nice(leader.pid)
        assert before is not None
        assert set_group_nice(child, 12)
        assert group_nice(leader.pid) == before == group_nice(child)
        assert set_group_nice(leader.pid, 12)
        assert group_nice(child) == 12  # the same group, written through its leader
    finally:
        os.killpg(leader.pid, 9)
        leader.wait()


# the kernel lets a writer without CAP_SYS_ADMIN change a group's nice once per 100 ms (system-wide)
RATE_LIMITED = (
    "import ctypes, os\n"
    "from agents.priority import set_group_nice  # first: the interpreter's files may be root's alone\n"
    "if os.getuid() == 0:  # as the tests' root, no limit applies: drop the privilege\n"
    "    os.setgid(65534); os.setuid(65534)\n"
    "    ctypes.CDLL(None).prctl(4, 1, 0, 0, 0)  # PR_SET_DUMPABLE: /proc/self stays this user's\n"
    "me, refused = os.getpid(), False\n"
    "for nice in range(1, 6):  # a stall of 100 ms between two lines lets the second through: try again\n"
    "    assert set_group_nice(me, nice, retry_s=2.0)\n"
    "    if not set_group_nice(me, nice + 10):\n"
    "        refused = True\n"
    "        break\n"
    "waited = set_group_nice(me, 19, retry_s=2.0)\n"
    "print(refused, waited, open(f'/proc/{me}/autogroup').read().split()[-1])\n"
)


def test_a_group_write_refused_for_the_rate_limit_is_retried_until_its_deadline(busy):
    out = subprocess.run([sys.executable, "-c", RATE_LIMITED], start_new_session=True, capture_output=True,
                         text=True, timeout=30, cwd=Path(__file__).resolve().parent.parent)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "True", "19"]  # refused without a retry; done with one
