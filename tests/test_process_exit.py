"""Waiting for agent processes takes no worker of the loop's default executor: with more running
children than it has workers, `to_thread` calls (the Platform's services) still run at once. An agent
process's leftover children die with it, before it is reaped. A run ends (AgentProcess.end) once its
agent has logged out and it has been killed, not once the kernel has torn its process down."""
from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from agents.process import AgentProcess, exit_future
from xmpp_server.settings import XmppSettings


async def test_running_children_do_not_starve_to_thread():
    n = (min(32, (os.cpu_count() or 1) + 4)) + 2  # more than the default executor's workers
    children = [subprocess.Popen([sys.executable, "-c", "import time; time.sleep(3)"]) for _ in range(n)]
    exits = [exit_future(p) for p in children]
    try:
        t0 = time.monotonic()
        assert await asyncio.wait_for(asyncio.to_thread(lambda: 42), 2.0) == 42
        assert time.monotonic() - t0 < 1.0
        assert not any(f.done() for f in exits)
    finally:
        for p in children:
            p.kill()
    codes = await asyncio.wait_for(asyncio.gather(*exits), 10)
    assert codes == [-9] * n


async def test_exit_code_is_reported():
    p = subprocess.Popen([sys.executable, "-c", "raise SystemExit(7)"])
    assert await asyncio.wait_for(exit_future(p), 10) == 7


async def test_the_sweep_before_reaping_does_not_hold_the_loop():
    """before_reap waits for what a run left to go (kill_uid, cgroup.kill: up to seconds); the loop
    that serves every other agent's messages turns meanwhile, and the exit is reported after it."""
    swept = []

    def slow_sweep() -> None:
        time.sleep(0.6)
        swept.append(time.monotonic())

    p = subprocess.Popen([sys.executable, "-c", "raise SystemExit(5)"])
    done = exit_future(p, before_reap=slow_sweep)
    gaps, last = [], time.monotonic()
    while not done.done():
        await asyncio.sleep(0.01)
        now = time.monotonic()
        gaps.append(now - last)
        last = now
    assert await done == 5 and swept
    assert max(gaps) < 0.3, f"the loop stood still for {max(gaps):.2f} s"


def test_sweeps_that_block_do_not_starve_to_thread():
    """Many runs ending at once each sweep what they left (up to seconds): on the loop's default
    executor the sweeps held its few workers and every `to_thread` of the Platform and the Core in
    the same process waited behind them. Here the default executor has a single worker (on a loop
    of this test's own: the session's loop keeps its executor)."""
    asyncio.run(_sweeps_block_while_to_thread_runs())


async def _sweeps_block_while_to_thread_runs():
    import concurrent.futures
    import threading

    loop = asyncio.get_running_loop()
    loop.set_default_executor(concurrent.futures.ThreadPoolExecutor(1))
    release = threading.Event()
    procs = [subprocess.Popen([sys.executable, "-c", "raise SystemExit(6)"]) for _ in range(3)]
    done = [exit_future(p, before_reap=lambda: release.wait(10)) for p in procs]
    try:
        for p in procs:  # exited (not reaped: the sweeps hold the reaping)
            os.waitid(os.P_PID, p.pid, os.WEXITED | os.WNOWAIT)
        await asyncio.sleep(0.2)  # the loop has seen the exits and handed the sweeps out
        assert not any(f.done() for f in done)
        t0 = time.monotonic()
        assert await asyncio.wait_for(asyncio.to_thread(lambda: 42), 5.0) == 42
        assert time.monotonic() - t0 < 1.0
    finally:
        release.set()
    assert await asyncio.wait_for(asyncio.gather(*done), 10) == [6, 6, 6]


def test_a_forked_child_sweeps_with_a_sweeper_of_its_own():
    """The sweeper's threads are not in a forked child: it starts its own there instead of queueing
    sweeps for threads that do not exist."""
    async def one_exit() -> int:
        p = subprocess.Popen([sys.executable, "-c", "raise SystemExit(9)"])
        return await asyncio.wait_for(exit_future(p, before_reap=lambda: None), 10)

    assert asyncio.run(one_exit()) == 9  # the parent's sweeper exists, with a thread
    pid = os.fork()
    if pid == 0:
        try:
            os._exit(0 if asyncio.run(one_exit()) == 9 else 1)
        except BaseException:  # noqa: BLE001 - a forked child never returns into pytest
            os._exit(2)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0


async def test_a_sweep_that_fails_still_reaps_and_reports_the_exit():
    def failing_sweep() -> None:
        raise OSError("no such control group")

    p = subprocess.Popen([sys.executable, "-c", "raise SystemExit(4)"])
    assert await asyncio.wait_for(exit_future(p, before_reap=failing_sweep), 10) == 4
    assert p.returncode == 4  # reaped: no zombie left


LEAVES_A_CHILD = ("import subprocess, sys; child = subprocess.Popen(['sleep', '60']); print(child.pid, flush=True); "
                  "sys.exit(3)")


async def test_an_agent_process_that_exits_takes_its_children_along(tmp_path):
    # nobody stops it: it exits by itself, leaving a child in its process group
    run = AgentProcess("leaves-a-child", None, tmp_path / "0001-child", XmppSettings())
    (tmp_path / "0001-child").mkdir()
    run.argv = [sys.executable, "-c", LEAVES_A_CHILD]
    await run.start()
    assert await asyncio.wait_for(run.wait(), 20) == 3
    child = int((Path(run.workdir) / "stdout.log").read_text().split()[0])
    deadline = time.monotonic() + 5
    while _exists(child) and time.monotonic() < deadline:  # SIGKILLed: gone once its parent's init reaps it
        await asyncio.sleep(0.05)
    assert not _exists(child)
    assert not run.alive() and await run.stop() == 3  # stopping an ended run signals nothing


def _exists(pid: int) -> bool:
    """Alive, a zombie not counted (a killed orphan waits for init to reap it)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


async def test_a_run_ends_once_its_agent_has_logged_out_and_is_reaped_after(settings, tmp_path, unique):
    from agents.process import spawn_agent
    from agents.tracing import read_trace

    from .test_warm_pool import cloud_spec, logged_in, run_dir

    spec = cloud_spec(settings, unique)
    run = spawn_agent(spec, run_dir(tmp_path, 1), settings)
    await run.start()
    await logged_in(settings, spec)
    code = await asyncio.wait_for(run.end(grace=5.0), 10)
    jid = settings.jid(spec.name)
    # by the time end() returns the agent has logged out (its own record) and cannot act again
    assert [r for r in read_trace(settings.trace_file) if r["kind"] == "agent" and r["event"] == "stopped"
            and r["agent"] == jid]
    assert code in (None, 143, -9)  # None: still being torn down, killed
    assert await asyncio.wait_for(run.wait(), 10) in (143, -9) and not run.alive()


IGNORES_SIGTERM = "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('up', flush=True); time.sleep(60)"


async def test_a_run_that_never_logs_out_is_killed_at_the_end_of_its_grace(tmp_path):
    run = AgentProcess("stubborn", None, tmp_path / "0001-stubborn", XmppSettings())
    (tmp_path / "0001-stubborn").mkdir()
    run.argv = [sys.executable, "-c", IGNORES_SIGTERM]
    await run.start()
    deadline = time.monotonic() + 10
    while "up" not in (Path(run.workdir) / "stdout.log").read_text() and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    t0 = time.monotonic()
    await run.end(grace=0.5)
    assert 0.45 < time.monotonic() - t0 < 2.0
    assert await asyncio.wait_for(run.wait(), 10) == -9


def test_a_run_directorys_log_that_is_a_link_or_a_fifo_is_neither_followed_nor_waited_for(tmp_path):
    # a Cloud Agent restarts in its directory, which its last process (the run's uid) could change
    run = AgentProcess("left-links", None, tmp_path / "0001-app", XmppSettings())
    (tmp_path / "0001-app").mkdir()
    secret = tmp_path / "root-only"
    secret.write_text("a line of root's file\n")
    (run.workdir / "stderr.log").symlink_to(secret)
    os.mkfifo(run.workdir / "stdout.log")
    assert run.stderr_tail() == "" and run.last_words() == ""  # not quoted into a record
    t0 = time.monotonic()
    with pytest.raises(OSError):
        run._popen()  # refused at once, nothing appended to the link's target
    assert time.monotonic() - t0 < 5 and secret.read_text() == "a line of root's file\n"


@pytest.mark.skipif(os.geteuid() != 0, reason="a process of another uid: needs root")
def test_killing_a_uid_does_not_wait_for_its_zombies():
    """kill_uid runs before the run's process is reaped (its exit_future's before_reap, a warm
    worker's run): that process is a zombie of the uid then. Waiting for it to go blocked the
    Platform's and the Core's loops for kill_uid's whole timeout (2 s) at every warm run's end; a
    live process of the uid is still killed."""
    from agents.process import kill_uid

    uid = 1_999_999  # outside the sandbox's run uids (agents/sandbox.py UID_BASE)
    as_uid = [sys.executable, "-c", f"import os, time; os.setuid({uid}); time.sleep(float(os.environ['S']))"]
    zombie = subprocess.Popen(as_uid, env={**os.environ, "S": "0"})
    os.waitid(os.P_PID, zombie.pid, os.WEXITED | os.WNOWAIT)  # exited, not reaped
    live = subprocess.Popen(as_uid, env={**os.environ, "S": "30"})
    try:
        deadline = time.monotonic() + 10
        while os.stat(f"/proc/{live.pid}").st_uid != uid and time.monotonic() < deadline:
            time.sleep(0.01)
        t0 = time.monotonic()
        assert kill_uid(uid, timeout=2.0)
        assert time.monotonic() - t0 < 1.0
        assert live.wait(5) == -9
    finally:
        live.kill()
        live.wait()
        zombie.wait()


@pytest.mark.skipif(os.geteuid() != 0, reason="a process of another uid: needs root")
def test_a_process_whose_main_thread_exited_is_killed_all_the_same():
    """A RApp can end its main thread alone (SYS_exit): the process then reads as a zombie while its
    other threads run. kill_uid kills and waits for it like any other process of the uid."""
    from agents.process import kill_uid

    uid = 1_999_998
    code = ("import ctypes, os, threading, time; os.setuid(%d); "
            "threading.Thread(target=time.sleep, args=(30,)).start(); "
            "ctypes.CDLL(None).syscall(60, 0)" % uid)  # SYS_exit on x86-64: this thread only
    proc = subprocess.Popen([sys.executable, "-c", code])
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                state = open(f"/proc/{proc.pid}/stat").read().rsplit(")", 1)[1].split()[0]
            except OSError:
                state = ""
            if state == "Z" and len(os.listdir(f"/proc/{proc.pid}/task")) > 1:
                break
            time.sleep(0.01)
        else:
            pytest.skip("could not make a zombie leader with a live thread here")
        assert kill_uid(uid, timeout=5.0)
        assert proc.wait(5) == -9
    finally:
        proc.kill()
        proc.wait()
