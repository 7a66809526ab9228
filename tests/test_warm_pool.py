"""Warm workers (agents/warm_pool.py): a hand-off goes to a process started ahead of time, in its
own sandbox; the pool refills behind it; a worker that died while idle is never handed a RApp;
idle workers are killed and reaped when the pool closes. Real processes, a real XMPP server: the
worker becomes a Cloud Agent of the echo RApp and logs in with the spec's one-time identity."""
from __future__ import annotations

import asyncio
import contextlib
import os
import secrets
import shutil
import signal
import time
from pathlib import Path

import pytest

from agents.process import spawn_agent, sweep_run_dirs
from agents.tracing import read_trace
from agents.warm_pool import REFILL_AFTER_S, REFILL_NICE, WarmPool
from ontology.spawn import SpawnSpec

ECHO_APP = Path(__file__).parent / "fixtures" / "echo_app"


def run_dir(workdir: Path, n: int) -> Path:
    """A run directory as the Core/Platform leave it before the spawn: the unpacked package only."""
    run = workdir / f"{n:04d}-echo-app"
    shutil.copytree(ECHO_APP, run / "package")
    return run


def cloud_spec(settings, unique) -> SpawnSpec:
    return SpawnSpec(kind="cloud", name=unique("warm-cloud"), password=secrets.token_urlsafe(16), package_dir="",
                     platform=settings.jid("nobody-platform"), owner=settings.jid("nobody"))


async def logged_in(settings, spec: SpawnSpec, timeout: float = 30.0) -> dict:
    """The agent's `started` trace record (written by the process that logged in)."""
    jid, deadline = settings.jid(spec.name), time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = [r for r in read_trace(settings.trace_file) if r["kind"] == "agent" and r["event"] == "started"
                 and r["agent"] == jid]
        if found:
            return found[0]
        await asyncio.sleep(0.05)
    raise AssertionError(f"{jid} did not log in within {timeout}s")


def thread_priorities(pid: int) -> set[int]:
    """The nice values of every thread of `pid` (Linux keeps one per thread), and of its session's
    autogroup where the kernel has them (agents/priority.py: across sessions only that one counts)."""
    found = {os.getpriority(os.PRIO_PROCESS, int(t)) for t in os.listdir(f"/proc/{pid}/task")}
    group = Path(f"/proc/{pid}/autogroup")
    words = group.read_text().split() if group.exists() else []  # empty: the root group
    if words:
        found.add(int(words[-1]))
    return found


def gone(pid: int) -> bool:
    """No such process (reaped, not a zombie)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def wait_for_zombie(pid: int, timeout: float = 5.0) -> None:
    """Block (on purpose: the event loop must not notice the exit first) until `pid` has exited."""
    deadline = time.monotonic() + timeout
    # the leader shows "Z" while its other threads (a Platform warm worker's BLAS threads) still exit, and
    # only then can it be reaped: wait for both
    while (Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
           or len(os.listdir(f"/proc/{pid}/task")) > 1):
        assert time.monotonic() < deadline, f"{pid} did not die"
        time.sleep(0.005)


async def test_a_hand_off_goes_to_the_prestarted_worker_and_the_pool_refills(settings, tmp_path, unique):
    pool = WarmPool(tmp_path, settings, size=1)
    pool.start()
    try:
        await pool.wait_ready(60)
        [worker] = pool.idle
        warm_dir, uid = worker.workdir, worker.uid
        run = run_dir(tmp_path, 1)
        spec = cloud_spec(settings, unique)
        agent = spawn_agent(spec, run, settings, pool=pool)
        await agent.start()
        assert agent.warm and agent.pid == worker.pid and agent.uid == uid
        assert (await logged_in(settings, spec))["pid"] == worker.pid  # the worker became the agent
        # its directory took the run's name: package, logs, tmp; the warm directory is no more
        assert not warm_dir.exists() and {"package", "stdout.log", "stderr.log", "tmp"} <= set(os.listdir(run))
        if uid is not None:  # the sandbox: the package is the run's uid's, the process runs as it
            assert (run / "package" / "manifest.yaml").stat().st_uid == uid
            assert os.stat(f"/proc/{agent.agent_pid}").st_uid == uid  # the runtime, inside the sandbox
        # the run is at its parent's priority: the pool's first fill was, and the hand-off keeps it
        base = os.getpriority(os.PRIO_PROCESS, 0)
        assert worker.nice == 0 and thread_priorities(agent.pid) == {base}
        # refilled in the background (a new process, a new uid) at nice 19: with both of the suite's workers
        # busy it gets under 1 % of a core, and its imports take ~1 s of CPU (CI at load 10 waited > 60 s)
        await pool.wait_ready(240)
        [fresh] = pool.idle
        assert fresh.pid != worker.pid and pool.started == 2
        assert uid is None or fresh.uid != uid
        assert await agent.stop(grace=0.5) is not None and gone(agent.pid)
    finally:
        await pool.close()
    assert pool.idle == [] and fresh.returncode is not None and gone(fresh.pid)  # idle: killed, reaped
    assert not fresh.workdir.exists()


async def test_a_pool_holding_its_running_workers_refills_when_the_run_ends(settings, tmp_path, unique):
    """hold_running (a Core's pool: one RApp at a time): no refill beside the run, one when it ends."""
    pool = WarmPool(tmp_path, settings, size=1, hold_running=True)
    pool.start()
    try:
        await pool.wait_ready(60)
        [worker] = pool.idle
        agent = spawn_agent(cloud_spec(settings, unique), run_dir(tmp_path, 1), settings, pool=pool)
        await agent.start()
        assert agent.warm and agent.pid == worker.pid
        await asyncio.sleep(REFILL_AFTER_S + 1.0)  # a refill would have been launched by now
        assert pool.idle == [] and pool.started == 1
        assert await agent.stop(grace=0.5) is not None
        await pool.wait_ready(240)
        [fresh] = pool.idle
        assert fresh.pid != worker.pid and pool.started == 2
    finally:
        await pool.close()


@contextlib.asynccontextmanager
async def refilling(settings, tmp_path):
    """A pool of one whose refills wait at a lower priority: (pool, this process's nice, the runs
    handed out, stopped at the end)."""
    pool = WarmPool(tmp_path, settings, size=1)
    if not pool.refill_nice:
        pytest.skip("this process may not raise a child's priority back (not root, RLIMIT_NICE)")
    runs = []
    pool.start()
    try:
        yield pool, os.getpriority(os.PRIO_PROCESS, 0), runs
    finally:
        for run in runs:
            await run.stop(grace=0.5)
        await pool.close()


async def test_a_refill_waits_at_a_lower_priority_and_its_run_gets_the_parents(settings, tmp_path, unique):
    """After a burst of hand-offs the refills must not slow the runs just started."""
    async with refilling(settings, tmp_path) as (pool, base, runs):
        for n in (1, 2):
            await pool.wait_ready(60)
            [worker] = pool.idle
            assert thread_priorities(worker.pid) == ({base} if n == 1 else {min(19, base + REFILL_NICE)})
            runs.append(spawn_agent(cloud_spec(settings, unique), run_dir(tmp_path, n), settings, pool=pool))
            await runs[-1].start()
            assert runs[-1].warm and runs[-1].pid == worker.pid and thread_priorities(worker.pid) == {base}


async def test_a_refill_handed_a_run_before_it_lowered_itself_still_runs_at_the_parents(settings, tmp_path, unique):
    """A worker lowers its own priority first thing (agents/sandbox.py confine). Handed a run before
    it got that far, it used to lower itself after the hand-off had raised it, and ran the whole
    RApp at nice 19: a silent-echo took 27 s to start on a loaded machine."""
    async with refilling(settings, tmp_path) as (pool, base, runs):
        await pool.wait_ready(60)
        runs.append(spawn_agent(cloud_spec(settings, unique), run_dir(tmp_path, 1), settings, pool=pool))
        await runs[-1].start()
        while not pool.idle:  # the refill, REFILL_AFTER_S later: taken the moment it is started
            await asyncio.sleep(0.001)
        [refill] = pool.idle
        assert not refill.ready
        spec = cloud_spec(settings, unique)
        runs.append(spawn_agent(spec, run_dir(tmp_path, 2), settings, pool=pool))
        await runs[-1].start()
        assert runs[-1].warm and runs[-1].pid == refill.pid
        await logged_in(settings, spec)
        await asyncio.sleep(0.2)
        assert thread_priorities(refill.pid) == {base}


async def test_a_worker_that_died_idle_is_replaced_never_handed_a_rapp(settings, tmp_path, unique):
    pool = WarmPool(tmp_path, settings, size=1)
    pool.start()
    try:
        await pool.wait_ready(60)
        [first] = pool.idle
        os.kill(first.pid, signal.SIGKILL)  # dies while idle: noticed through its exit future
        await asyncio.wait_for(first.exited(), 10)
        assert pool.lost == 1 and first not in pool.idle and first.proc.returncode == -signal.SIGKILL
        await pool.wait_ready(60)  # replaced (after a short back-off)
        [second] = pool.idle
        assert second.pid != first.pid and not first.workdir.exists()
        run = run_dir(tmp_path, 1)
        spec = cloud_spec(settings, unique)
        agent = spawn_agent(spec, run, settings, pool=pool)
        os.kill(second.pid, signal.SIGKILL)
        wait_for_zombie(second.pid)  # dead, and the loop has not run since: the pool does not know yet
        await agent.start()  # (runs up to the pool's take() without giving the loop a turn)
        try:
            assert not agent.warm and agent.pid not in (first.pid, second.pid)  # a cold start instead
            assert (await logged_in(settings, spec))["pid"] == agent.pid
            assert second.proc.returncode == -signal.SIGKILL and pool.lost == 2
        finally:
            await agent.stop(grace=0.5)
    finally:
        await pool.close()


async def test_a_cloud_worker_logs_in_while_idle_and_its_account_goes_with_it(settings, tmp_path, unique):
    """The Platform's pool (login=): each worker logs in under an account of its own before any run;
    its run (a spec naming that account) is served by the agent already logged in, its RApp code
    imported only then; an idle worker let go takes its account along."""
    from agents.identity import EphemeralAccounts
    from xmpp_server.probe import LoginError, probe_login

    settings = settings.model_copy(update={"credentials_dir": tmp_path / "credentials"})
    accounts = EphemeralAccounts(settings, owner=unique("pool"))
    async def reserve():  # as the Platform does: the worker registers the account at its login
        return accounts.reserve(unique("cloud"))

    pool = WarmPool(tmp_path / "runs", settings, size=1, login=reserve,
                    forget=lambda ident: accounts.delete(ident.name, ident.password))
    pool.start()
    try:
        await pool.wait_ready(60)  # ready = logged in
        worker = pool.take()
        ident = worker.login
        spec = cloud_spec(settings, unique).model_copy(update={"name": ident.name, "password": ident.password})
        assert (await logged_in(settings, spec))["pid"] == worker.pid  # before any run
        handed = time.time()
        run = run_dir(tmp_path / "runs", 1)
        agent = spawn_agent(spec, run, settings)
        await agent.start(worker=worker)
        assert agent.warm and agent.pid == worker.pid and agent.login is ident
        jid = settings.jid(ident.name)
        deadline = time.monotonic() + 30
        while not [r for r in read_trace(settings.trace_file) if r["kind"] == "behaviour" and r["agent"] == jid
                   and r["behaviour"] == "cloud-service" and r["event"] == "activated"]:
            assert time.monotonic() < deadline, "the logged-in worker never served its run"
            await asyncio.sleep(0.05)
        starts = [r for r in read_trace(settings.trace_file) if r["kind"] == "agent" and r["event"] == "started"
                  and r["agent"] == jid]
        assert len(starts) == 1 and starts[0]["t"] < handed  # no second login for the run
        await pool.wait_ready(60)
        [fresh] = pool.idle
        assert fresh.login.name != ident.name
        await agent.stop(grace=0.5)
    finally:
        await pool.close()
    assert gone(fresh.pid)
    with pytest.raises(LoginError, match="authentication failed"):  # the idle one's account is no more
        await probe_login(settings.host, settings.port, settings.domain, user=fresh.login.name,
                          password=fresh.login.password, register=False)
    await probe_login(settings.host, settings.port, settings.domain, user=ident.name, password=ident.password,
                      register=False)  # the run's account is its owner's to remove (the Platform's clean-up)
    assert await accounts.delete(ident.name, ident.password) and accounts.pending() == {}


async def test_a_logged_in_worker_handed_another_accounts_run_refuses_it(settings, tmp_path, unique):
    from agents.identity import EphemeralAccounts

    settings = settings.model_copy(update={"credentials_dir": tmp_path / "credentials"})
    accounts = EphemeralAccounts(settings, owner=unique("pool"))
    pool = WarmPool(tmp_path / "runs", settings, size=1, login=lambda: accounts.create(unique("cloud")),
                    forget=lambda ident: accounts.delete(ident.name, ident.password))  # made ahead: works too
    pool.start()
    try:
        await pool.wait_ready(60)
        worker = pool.take()
        agent = spawn_agent(cloud_spec(settings, unique), run_dir(tmp_path / "runs", 1), settings)
        await agent.start(worker=worker)
        assert await asyncio.wait_for(agent.wait(), 30) != 0
        assert f"logged in as {worker.login.name} was handed cloud run" in agent.stderr_tail()
    finally:
        await pool.close()
        await accounts.sweep()


async def test_pool_size_and_crash_leftovers(settings, tmp_path):
    with pytest.raises(ValueError, match="warm_workers"):
        WarmPool(tmp_path, settings, size=-1)
    off = WarmPool(tmp_path, settings, size=0)
    off.start()
    assert off.take() is None and off.started == 0
    await off.close()
    (tmp_path / "0007-.warm" / "tmp").mkdir(parents=True)  # an idle worker's directory after a crash
    (tmp_path / "0002-echo-app").mkdir()
    sweep_run_dirs(tmp_path)
    assert os.listdir(tmp_path) == []


def test_a_pool_refuses_what_is_not_a_module_name_to_import_ahead(settings, tmp_path):
    """The names travel to the sandboxed worker in its environment: only dotted identifiers."""
    with pytest.raises(ValueError, match="not module names"):
        WarmPool(tmp_path, settings, preload=("numpy", "os; import shutil", ""))
    assert WarmPool(tmp_path, settings, preload=("rapps.sdk", "scipy.optimize")).preload == ("rapps.sdk", "scipy.optimize")


def test_the_runtime_imports_the_extra_modules_it_is_given_and_skips_missing_ones():
    import subprocess
    import sys

    code = ("import sys; from agents.runtime import preload; preload(('rapps.sdk', 'no_such_module_x'));"
            "print('rapps.sdk' in sys.modules, 'rapps.sdk.vision' in sys.modules)")
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=60)
    assert done.stdout.split() == ["True", "False"], done.stderr[-1500:]  # a missing one is skipped


async def test_a_module_left_in_a_run_directory_is_not_imported_before_the_sandbox(settings, tmp_path, unique):
    # a restarted Cloud Agent starts in its old directory, which its last process could write into;
    # the runtime imports as root until it confines itself: the directory must not be on its path
    run = run_dir(tmp_path, 1)
    marker = tmp_path / "imported-from-the-run-directory"
    (run / "yaml.py").write_text(f"open({str(marker)!r}, 'w').close()\nfrom yaml_real_is_gone import x\n")
    spec = cloud_spec(settings, unique)
    agent = spawn_agent(spec, run, settings)
    await agent.start()
    try:
        started = await logged_in(settings, spec, timeout=20)  # it started, with the real yaml
    except AssertionError:
        started = None
    finally:
        await agent.stop(grace=0.5)
    assert not marker.exists() and started
