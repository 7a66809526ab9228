"""Child processes for Dynamic and Cloud Agents (the paper's fork-exec), always reaped.

Each child runs in its own session (so the whole group can be killed), in the sandbox of
agents/sandbox.py and agents/confine.py (its own namespaces, root, uid, control group and working
directory), with rlimits, stdout/stderr to files in that directory. `stop()` sends SIGTERM, then
SIGKILL after a grace period (the sandbox's init with it: its PID namespace dies whole; its control
group is killed too), then waits: no zombie is ever left behind. `InProcessAgent` runs the same runtime as a task of the caller: no isolation
at all, for tests and for measuring what the process costs.
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from ontology.spawn import SpawnSpec, WarmLogin

from .cgroups import RunGroup, release_if_used
from .limits import Limits
from .priority import each_thread, set_priority
from .sandbox import APP_DIR, CONFINE_ENV, Sandbox, give_tree, open_run_file
from .tracing import TraceRelay, tracer_for

log = logging.getLogger("rapp.process")

# a refill handed a run waits this long at most for the worker to confine itself (it does within ~0.1 s
# of its start, at its parent's priority, before lowering it)
CONFINED_WITHIN_S = 5.0


# The sweeps before reaping (exit_future's before_reap: up to ~2 s each) run on an executor of their own:
# on the loop's default one, many runs ending at once held its few workers and starved every
# `to_thread` of the Platform and the Core in the same process. Its threads are joined at interpreter
# exit (concurrent.futures does), so a sweep under way still kills what its run left; each sweep is
# bounded by its own timeout. A forked child drops the parent's (its threads are not in the child).
SWEEPERS = 8  # threads start only as sweeps overlap; no fewer than the default executor's on 2 cores (6)
_sweeper = None
_sweeper_lock = threading.Lock()


def _sweeper_pool():
    global _sweeper
    with _sweeper_lock:
        if _sweeper is None:
            from concurrent.futures import ThreadPoolExecutor
            _sweeper = ThreadPoolExecutor(SWEEPERS, thread_name_prefix="rapp-sweep")
        return _sweeper


def _forget_sweeper() -> None:
    global _sweeper, _sweeper_lock
    _sweeper, _sweeper_lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_sweeper)


def exit_future(proc: subprocess.Popen, before_reap=None) -> asyncio.Future:
    """Resolves with the process's return code when it exits. The loop watches a pidfd; a thread
    blocked in `proc.wait()` would hold one of the loop's default executor's few workers for the
    process's whole life (20 running Dynamic Agents starved every `to_thread` call of the Platform
    in the same process). Without pidfds (not Linux), a daemon thread of its own waits.
    `before_reap()` runs once the process has exited and before it is reaped: while its pid cannot
    yet be another process's (AgentProcess kills what is left of its process group then), on the
    sweepers' executor (above), never the loop's default one."""
    loop = asyncio.get_running_loop()
    fut = loop.create_future()

    def resolve(code: int) -> None:
        if not fut.done():
            fut.set_result(code)

    def sweep() -> None:
        if before_reap is not None and proc.returncode is None:
            try:
                before_reap()
            except Exception:  # noqa: BLE001 - the process is reaped all the same
                log.exception("the sweep before reaping process %d failed", proc.pid)

    def reap() -> int:
        sweep()
        return proc.wait()

    try:
        fd = os.pidfd_open(proc.pid)
    except (AttributeError, OSError):
        def wait_then_reap() -> None:
            try:
                os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOWAIT)  # exited, not reaped
            except ChildProcessError:
                pass
            loop.call_soon_threadsafe(resolve, reap())
        threading.Thread(target=wait_then_reap, name=f"wait-{proc.pid}", daemon=True).start()
        return fut

    def exited() -> None:
        loop.remove_reader(fd)
        os.close(fd)
        if before_reap is None:
            resolve(reap())  # already exited: reaps at once
        else:  # the sweep waits for what is left to go (up to seconds): in a thread, not on the loop; the
            # reaping stays on the loop, so the future is done as the pid is freed (AgentProcess signals
            # the group only while its future is not done: the pid is still this process's)
            def sweep_then_reap() -> None:
                sweep()
                try:
                    loop.call_soon_threadsafe(lambda: resolve(proc.wait()))
                except RuntimeError:  # its loop has closed meanwhile: reaped here, never left a zombie
                    proc.wait()

            try:
                _sweeper_pool().submit(sweep_then_reap)
            except RuntimeError:  # the interpreter is exiting: no new executor threads; sweep here
                sweep()
                resolve(proc.wait())

    loop.add_reader(fd, exited)
    return fut


def _on_byte(fd: int, event: asyncio.Event) -> None:
    """Set `event` when `fd` (a pipe's read end, closed then) gives a byte or its end."""
    loop = asyncio.get_running_loop()

    def readable() -> None:
        loop.remove_reader(fd)
        try:
            os.read(fd, 1)
        except OSError:
            pass
        os.close(fd)
        event.set()
    loop.add_reader(fd, readable)


def _kill_group(pgid: int, sig: int = signal.SIGKILL) -> None:
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _dead(pid: int) -> bool:
    """Exited, not yet reaped (or being reaped), every thread of it gone: nothing left to kill. A
    leader that ended its own thread alone (SYS_exit) reads as a zombie while its other threads run:
    not dead."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read()
        return stat[stat.rindex(b")") + 2:][:1] in (b"Z", b"X") and len(os.listdir(f"/proc/{pid}/task")) <= 1
    except OSError:
        return True


def kill_uid(uid: int, timeout: float = 2.0) -> bool:
    """Every process of `uid` killed, /proc scanned again until none is left (one scan misses a
    process forked meanwhile); False if some were still there after `timeout`. A dead zombie counts as
    gone: the run's own process is one while this runs before its reaping (exit_future's
    before_reap), and waiting for it to go blocked the caller's loop for the whole `timeout`."""
    deadline = time.monotonic() + timeout
    while True:
        found = 0
        for entry in os.scandir("/proc"):
            if entry.name.isdigit():
                pid = int(entry.name)
                try:
                    if entry.stat().st_uid == uid:
                        os.kill(pid, signal.SIGKILL)  # a zombie too: harmless, and a live thread of it dies
                        found += not _dead(pid)
                except OSError:
                    pass
        if not found:
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)


def _widen(fd: int, size: int = 1 << 20) -> None:
    """A pipe's buffer made larger (a RApp's burst of trace records blocks it less)."""
    try:
        import fcntl
        fcntl.fcntl(fd, 1031, size)  # F_SETPIPE_SZ
    except OSError:
        pass


def _running(proc: subprocess.Popen) -> bool:
    """Not exited yet, without reaping it (Popen.poll would: exit_future reaps, after before_reap)."""
    if proc.returncode is not None:
        return False
    try:
        return os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is None
    except ChildProcessError:  # reaped by someone else
        return False


def sweep_run_dirs(workdir: Path, remove_root: bool = False) -> None:
    """Remove the run directories (`NNNN-<rapp>`: package, logs; idle warm workers' `NNNN-.warm`)
    under a Core's or Platform's work directory: at stop, and at start for those a crash left behind."""
    workdir = Path(workdir)
    release_if_used()  # the sandbox's base control groups, where no run is left in them
    if remove_root:
        shutil.rmtree(workdir, ignore_errors=True)
        return
    for run in workdir.glob("[0-9][0-9][0-9][0-9]-*"):
        shutil.rmtree(run, ignore_errors=True)


class AgentProcess:
    """A Dynamic or Cloud Agent in a process of its own, in the sandbox (agents/sandbox.py): the
    spec (with the run's one-time password) goes down an inherited pipe, the trace through an
    append-only descriptor; the environment is an allow-list.

    Without a spec it is a warm worker (agents/warm_pool.py): started ahead of time in a run
    directory of its own, it imports the runtime, says so on a second pipe and blocks reading its
    spec. With a `pool`, `start()` takes such a worker when one is idle and hands it this run: the
    package moves into the worker's directory, which then takes this run's name, and the spec goes
    down the worker's pipe; without one idle it starts a process as before (a cold start). A
    worker with a `login` (the Platform's Cloud workers) got its account down the same pipe first
    and is logged in: the caller takes it and passes it to `start(worker=)` with a spec naming it."""

    def __init__(self, name: str, spec: SpawnSpec | None, workdir: Path, settings, limits: Limits = Limits(),
                 sandbox: Sandbox | None = None, pool=None, preload: tuple[str, ...] = (), nice: int = 0,
                 login=None):
        self.name = name
        # a warm Cloud worker's own account (agents/identity.py Identity), logged in while idle; its
        # run's spec names the same account
        self.login = login
        self.preload = check_module_names(preload)  # a warm worker imports these too (agents/runtime.py)
        self.nice = nice  # a warm worker's priority while idle (raised back at its hand-off)
        self.workdir = Path(workdir)
        self.settings, self.limits = settings, limits
        self.sandbox = sandbox or Sandbox()
        self.pool = pool
        self.uid = self.sandbox.new_uid()
        self._given = spec
        self.spec = self._placed(spec) if spec is not None else None
        # -P: the run directory (its cwd, which a restarted run's last process could write into) is
        # not on sys.path: the runtime imports as root until it has confined itself
        self.argv = [sys.executable, "-P", "-m", "agents.runtime"]
        self.proc: subprocess.Popen | None = None
        self._waiter: asyncio.Future | None = None
        self._spec_w: int | None = None  # a warm worker's end of its spec pipe, until the hand-off
        self._ready_r: int | None = None  # a warm worker's "imports done" pipe, until it says so
        self.ready = False  # a warm worker that has imported the runtime
        self.confined = asyncio.Event()  # a warm worker that has confined itself (or died)
        self._logged_out = asyncio.Event()  # said on its "gone" pipe (agents/runtime.py), or exited
        self._gone_r: int | None = None  # that pipe's read end, until start() watches it
        self.warm = False  # this run went to a warm worker (no interpreter start on the hand-off)
        self.returncode: int | None = None
        self.cgroup: RunGroup | None = None
        self.runtime_pid: int | None = None  # the runtime's own process inside the sandbox (its P's grandchild)
        self.refusals: list[dict] = []  # what the sandbox refused the run (agents/confine.py), in order
        self.on_refusal = None  # called with each refusal as it comes (its Core or Platform traces it)
        self._report_r: int | None = None  # the sandbox's report pipe, until its end
        self._trace: TraceRelay | None = None

    @property
    def sandboxed(self) -> bool:
        return self.sandbox.enabled

    def identity(self) -> str:
        """The run's JID (a warm worker not handed a run yet: its login's, or "warm worker")."""
        name = self.spec.name if self.spec is not None else (self.login.name if self.login else None)
        return self.settings.jid(name) if name else "warm-worker"

    @property
    def agent_pid(self) -> int | None:
        """The runtime's process (what a liveness check looks at): inside the sandbox, its init's
        child; the process started otherwise."""
        return self.runtime_pid or self.pid

    def _placed(self, spec: SpawnSpec) -> SpawnSpec:
        package = f"{APP_DIR}/package" if self.sandboxed else str(self.workdir.resolve() / "package")
        return spec.model_copy(update={"package_dir": package})

    async def start(self, worker: "AgentProcess | None" = None) -> None:
        """`worker`: an idle warm worker the caller took from its pool (a logged-in Cloud worker,
        whose account the spec names); else one is taken from `pool`, if any."""
        if self.spec is not None and _fresh(self.workdir):
            if worker is None and self.pool is not None:
                worker = self.pool.take()
            if worker is not None and await self._become(worker):
                return
        elif worker is not None:
            await worker.stop(grace=0.0)  # not for this run: never left idle outside its pool
        # Popen + a pidfd, not asyncio subprocesses: SPADE installs uvloop's loop policy,
        # whose child watcher the standard loop cannot use.
        self.proc = await asyncio.to_thread(self._popen)
        # what is left of its process group and control group (a RApp's children) dies with it, whoever ends it
        self._waiter = exit_future(self.proc, before_reap=self._kill_leftovers)
        self._waiter.add_done_callback(lambda _: self._logged_out.set())
        self._waiter.add_done_callback(lambda _: self._after_exit())
        loop = asyncio.get_running_loop()
        if self._report_r is not None:
            loop.add_reader(self._report_r, self._sandbox_said)
        if self._trace is not None:
            self._trace.start(loop)
        _on_byte(self._gone_r, self._logged_out)
        self._gone_r = None
        if self._ready_r is not None:
            asyncio.get_running_loop().add_reader(self._ready_r, self._ready_said)

    async def _become(self, worker: "AgentProcess") -> bool:
        """This run goes to the idle warm `worker`: same process, uid, sandbox and exit future.
        False when the worker died after the pool checked it: reaped, and the run starts cold."""
        if worker.nice and not worker.confined.is_set():
            # a refill just started lowers its own priority first thing (agents/sandbox.py confine):
            # raised before that, it ran the whole RApp at nice 19 (27 s to start on a loaded machine)
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(worker.confined.wait(), CONFINED_WITHIN_S)
        self.uid, self.proc, self._waiter, self.login = worker.uid, worker.proc, worker._waiter, worker.login  # noqa: SLF001 - same class
        self._logged_out = worker._logged_out  # noqa: SLF001 - same class
        self.cgroup, self.runtime_pid, self.refusals = worker.cgroup, worker.runtime_pid, worker.refusals
        worker.cgroup = None  # this run's to clean up now
        self._report_r, worker._report_r = worker._report_r, None  # noqa: SLF001 - same class
        if self._report_r is not None:  # the worker's events are this run's now
            loop = asyncio.get_running_loop()
            loop.remove_reader(self._report_r)
            loop.add_reader(self._report_r, self._sandbox_said)
        self._waiter.add_done_callback(lambda _: self._after_exit())
        self._trace, worker._trace = worker._trace, None  # noqa: SLF001 - same class
        if self._trace is not None:
            self._trace.who, self._trace.pid = self.identity, lambda: self.pid
        spec_w, worker._spec_w = worker._spec_w, None  # noqa: SLF001 - same class
        worker._forget_ready()  # noqa: SLF001 - same class
        self.spec, self.warm = self._placed(self._given), True
        try:
            await asyncio.to_thread(self._hand_over, worker.workdir, spec_w, worker.nice)
            return True
        except BrokenPipeError:
            await self.stop(grace=0.0)
            self.proc = self._waiter = self.returncode = self.cgroup = self.runtime_pid = None
            self.refusals, self._report_r, self._trace = [], None, None
            self._logged_out = asyncio.Event()
            self.uid, self.warm, self.login = self.sandbox.new_uid(), False, None  # a fresh uid for the cold start
            self.spec = self._placed(self._given)
            return False
        except BaseException:
            await self.stop(grace=0.0)  # a worker whose hand-off failed is never left running
            raise

    def _hand_over(self, warm_dir: Path, spec_w: int, worker_nice: int = 0) -> None:
        """Package into the worker's directory (its /app), given to its uid as Sandbox.prepare
        does; the directory takes this run's name (the worker's bind mount follows the directory,
        not its name); then the spec, which the worker has been blocked reading."""
        try:
            if worker_nice:  # the run at its parent's priority (the pool lowers it only where it may)
                self._at_parents_priority()
            os.replace(self.workdir / "package", warm_dir / "package")
            if self.uid is not None:
                give_tree(warm_dir / "package", self.uid)
            os.replace(warm_dir, self.workdir)  # onto the now empty NNNN-<rapp> directory
            os.write(spec_w, self._spec_bytes())
        finally:
            os.close(spec_w)

    def _spec_bytes(self) -> bytes:
        data = self.spec.model_dump_json().encode()
        if len(data) > 60_000:  # a pipe holds 64 KiB: the write must not block
            raise ValueError(f"spawn spec of {len(data)} bytes is too large")
        return data

    def _popen(self) -> subprocess.Popen:
        self.sandbox.prepare(self.workdir, self.uid)
        if self.sandboxed:
            try:
                self.cgroup = RunGroup.create(self.limits, self.nice)
            except OSError as e:  # said at start (agents/cgroups.py support): rlimits and the namespace still hold
                log.warning("no control group for %s: %s", self.name, e)
        spec_r, spec_w = os.pipe()
        gone_r, gone_w = os.pipe()  # "logged out" (agents/runtime.py say_logged_out)
        fds, keep = [spec_r, gone_w], []
        try:
            extra = {"RAPP_SPEC_FD": str(spec_r), "RAPP_GONE_FD": str(gone_w)}
            if self.spec is not None:
                try:
                    os.write(spec_w, self._spec_bytes())
                finally:
                    os.close(spec_w)
            else:  # a warm worker: the spec comes at the hand-off; "imports done" comes back
                if self.login is not None:  # its account first: it logs in while idle
                    os.write(spec_w, WarmLogin(name=self.login.name, password=self.login.password)
                             .model_dump_json().encode() + b"\n")
                    extra["RAPP_WARM_LOGIN"] = "1"
                keep.append(spec_w)
                ready_r, ready_w = os.pipe()
                keep.append(ready_r)
                fds.append(ready_w)
                extra["RAPP_READY_FD"] = str(ready_w)
                if self.preload:
                    extra["RAPP_PRELOAD"] = ",".join(self.preload)
            if self.settings.trace_file:  # a pipe this process reads: the child never holds the trace's file
                trace_r, trace_w = os.pipe2(os.O_CLOEXEC)
                keep.append(trace_r)
                fds.append(trace_w)
                _widen(trace_w)
                extra["RAPP_TRACE_FD"] = str(trace_w)
                self._trace = TraceRelay(trace_r, tracer_for(self.settings.trace_file), self.identity,
                                         lambda: self.pid)
            child_fds = tuple(fds)
            report_w = None
            if self.sandboxed:  # the sandbox's own events (its outer process writes them, never the RApp)
                self._report_r, report_w = os.pipe2(os.O_CLOEXEC)
                keep.append(self._report_r)
                fds.append(report_w)
            with open_run_file(self.workdir / "stdout.log", "ab") as out, open_run_file(self.workdir / "stderr.log", "ab") as err:
                # no preexec_fn: the runtime confines itself first thing (agents/sandbox.py confine)
                extra[CONFINE_ENV] = self.sandbox.confinement(self.uid, self.limits, self.nice, settings=self.settings,
                                                              cgroup=self.cgroup, report_fd=report_w,
                                                              child_fds=child_fds)
                proc = subprocess.Popen(
                    self.argv, cwd=self.workdir, env=self.sandbox.env(self.settings, extra), stdout=out,
                    stderr=err, stdin=subprocess.DEVNULL, start_new_session=True, pass_fds=fds)
        except BaseException:
            for fd in [*keep, gone_r]:
                os.close(fd)
            self._report_r = self._trace = None
            if self.cgroup is not None:
                self.cgroup.remove()
            raise
        finally:
            for fd in fds:
                os.close(fd)
        if self.spec is None:  # a warm worker: its spec pipe's write end and its "ready" pipe
            self._spec_w, self._ready_r = keep[:2]
        self._gone_r = gone_r
        return proc

    def _ready_said(self) -> None:
        try:
            said = os.read(self._ready_r, 1)
        except OSError:
            said = b""
        self.confined.set()  # b"c" comes first (agents/runtime.py say_confined); b"": it died
        if said == b"c":
            return
        self.ready = said == b"1"
        self._forget_ready()

    def _forget_ready(self) -> None:
        if self._ready_r is not None:
            asyncio.get_running_loop().remove_reader(self._ready_r)
            os.close(self._ready_r)
            self._ready_r = None

    def exited(self) -> asyncio.Future:
        """Resolves with the exit code once the process has exited and been reaped."""
        assert self._waiter is not None
        return self._waiter

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc else None

    def alive(self) -> bool:
        return self.proc is not None and _running(self.proc)

    async def wait(self) -> int:
        assert self._waiter is not None
        self.returncode = await asyncio.shield(self._waiter)
        return self.returncode

    async def logged_out(self, timeout: float) -> bool:
        """Whether the agent has logged out (or the process exited) within `timeout` s."""
        try:
            await asyncio.wait_for(self._logged_out.wait(), timeout)
        except asyncio.TimeoutError:
            pass
        return self._logged_out.is_set()

    async def end(self, grace: float = 1.0) -> int | None:
        """End the run as far as anyone else can tell: SIGTERM (the agent logs out cleanly), then,
        once it has logged out or after `grace` s, SIGKILL to it and its process group. Returns its
        exit code, or None while it is still exiting: the kernel's teardown of a process with SPADE,
        numpy and cv2 loaded takes 7-14 ms of CPU alone and took up to 200 ms under a fleet's load,
        and a logged-out process killed can no longer act. `wait()` gives the code once reaped."""
        if self.proc is None:
            return None
        if self.alive() and not self._logged_out.is_set():
            self._at_parents_priority()
            self._signal(signal.SIGTERM)
            await self.logged_out(grace)
        self._signal(signal.SIGKILL)  # its sandbox's init with it: the run's PID namespace dies whole
        # killed, not waited for: the exit future's sweep (before_reap) waits for the group to empty
        self._kill_leftovers(wait=False)
        self._forget_ready()
        if self._spec_w is not None:  # an idle warm worker: its spec never comes
            os.close(self._spec_w)
            self._spec_w = None
        return self._waiter.result() if self._waiter.done() else None

    async def stop(self, grace: float = 1.0) -> int | None:
        """end(), then wait until the process has been reaped: its exit code."""
        if self.proc is None:
            return None
        await self.end(grace)
        return await self.wait()

    def yield_cpu(self, by: int) -> None:
        """The run `by` nice steps below its parent, threads and session group alike; best effort
        (a group write refused for its rate limit leaves the group as it was)."""
        if self.proc is None or not self.alive():
            return
        nice = os.getpriority(os.PRIO_PROCESS, 0) + by
        try:
            set_priority(self.proc.pid, nice)  # the sandbox's outer process and its session's group
            if self.runtime_pid:  # the runtime itself, inside the sandbox (its init's child)
                each_thread(self.runtime_pid, lambda tid: os.setpriority(os.PRIO_PROCESS, tid, nice))
        except OSError:  # gone meanwhile, or a raise this user may not make
            pass
        if self.cgroup is not None:  # in a CPU group of its own, the group's weight is what counts
            self.cgroup.set_nice(by)

    def _at_parents_priority(self) -> None:
        """A run that lowered its priority (a Cloud Agent once serving, CLOUD_NICE) logs out and
        exits at its parent's where that is allowed (a fleet's stops at nice +5 took 90-135 ms
        under load, when they waited for the exit)."""
        try:
            if os.getpriority(os.PRIO_PROCESS, self.agent_pid) > os.getpriority(os.PRIO_PROCESS, 0):
                self.yield_cpu(0)
        except OSError:  # gone already
            pass

    def _signal(self, sig: int) -> None:
        if self._waiter is not None and self._waiter.done():
            return  # reaped: its pid may be another process's by now
        _kill_group(self.proc.pid, sig)

    def _kill_leftovers(self, wait: bool = True) -> None:
        """Whatever of the run is left: its process group, its control group (`cgroup.kill`), and,
        without a control group, every process of its uid, scanned again until none is left
        (`wait`; else one pass: the kernel's teardown of the killed processes, 20-80 ms, would hold
        up the caller's loop)."""
        if self.proc is not None and not (self._waiter is not None and self._waiter.done()):
            _kill_group(self.proc.pid, signal.SIGKILL)
        if self.cgroup is not None:
            self.cgroup.kill(timeout=0.5 if wait else 0.0)
        elif self.uid is not None:
            kill_uid(self.uid, timeout=2.0 if wait else 0.0)

    def _after_exit(self) -> None:
        """Reaped: the sandbox's last words read, what its control group was refused kept, the group gone."""
        if self._report_r is not None:
            self._sandbox_said()
        if self.cgroup is not None:
            for what, n in self.cgroup.refusals().items():
                self._refused({"event": "refused", "what": {"oom_kill": "memory (killed for its limit)",
                                                            "pids_max": "a new process (its process limit)"}[what],
                               "count": n})
            self.cgroup.kill(timeout=0.0)  # one pass: the sweep before the reaping waited, in a thread
            if not self.cgroup.remove():
                asyncio.get_running_loop().call_later(1.0, self.cgroup.remove)

    def _sandbox_said(self) -> None:
        fd = self._report_r
        try:
            data = os.read(fd, 65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            asyncio.get_running_loop().remove_reader(fd)
            os.close(fd)
            self._report_r = None
            return
        for line in data.splitlines():
            try:
                event = json.loads(line)
            except ValueError:
                continue
            if event.get("event") == "runtime":
                self.runtime_pid = int(event["pid"])
            elif event.get("event") == "refused":
                self._refused(event)
            elif event.get("event") == "upstream":
                log.warning("%s: the sandbox could not reach the XMPP server: %s", self.identity(), event.get("error"))

    def _refused(self, event: dict) -> None:
        entry = {"by": "sandbox", "what": str(event.get("what", ""))[:200], "count": int(event.get("count", 1)),
                 **({"why": str(event["why"])[:200]} if event.get("why") else {})}
        same = next((r for r in self.refusals if r["what"] == entry["what"]), None)
        if same is not None:
            same["count"] = max(same["count"], entry["count"])
        else:
            self.refusals.append(entry)
        if self.on_refusal is not None:
            try:
                self.on_refusal(entry)
            except Exception:  # noqa: BLE001 - a caller's error never stops the sandbox's reading
                log.exception("on_refusal")

    def stderr_tail(self, n: int = 2000) -> str:
        """The last ~n characters of its stderr.log: only those are read (a RApp may log megabytes)."""
        try:
            with open_run_file(self.workdir / "stderr.log", "rb") as f:
                f.seek(max(0, f.seek(0, os.SEEK_END) - 4 * n))  # up to 4 bytes a character
                return f.read().decode(errors="replace")[-n:]
        except OSError:
            return ""

    def last_words(self, n: int = 1500) -> str:
        """What the process wrote last: from its fault handler's "Fatal Python error" on (the
        Python stack of a crash, without the list of extension modules after it), else the tail."""
        text = self.stderr_tail(20_000)  # the dump lists every thread; the module list after it is long
        at = text.rfind(FATAL)
        if at < 0:
            return text[-n:]
        return text[at:].split("\nExtension modules:")[0][:n]


FATAL = "Fatal Python error"  # how faulthandler's dump of a crash begins (agents/runtime.py enables it)


def crash_summary(words: str) -> str | None:
    """One line of a crash's dump (last_words): what happened and the crashing thread's innermost
    frame (the dump lists every thread, most recent call first, the crashing one marked "Current");
    None when the words are no crash dump."""
    if not words.startswith(FATAL):
        return None
    lines = [ln.strip() for ln in words.splitlines() if ln.strip()]
    current = next((i for i, ln in enumerate(lines) if ln.startswith("Current thread")), 0)
    return " ".join([lines[0], *[ln for ln in lines[current:] if ln.startswith("File ")][:1]])


class InProcessAgent:
    """The AgentProcess interface for an agent run as a task of this process: the same package
    bytes, unpacking and runtime code, no isolation (no limits, a crash affects the caller).
    For fast tests and for measuring what the process costs."""

    uid = None  # never sandboxed
    sandboxed = False
    runtime_pid = None
    on_refusal = None

    def __init__(self, name: str, spec: SpawnSpec, workdir: Path, settings):
        self.name, self.workdir, self.settings = name, Path(workdir), settings
        self.spec = spec.model_copy(update={"package_dir": str(self.workdir / "package")})
        self.task: asyncio.Task | None = None
        self.agent = None
        self.returncode: int | None = None
        self.refusals: list[dict] = []

    @property
    def agent_pid(self) -> int:
        return os.getpid()

    def yield_cpu(self, by: int) -> None:  # its host's priority is not the RApp's to change
        pass

    async def start(self, worker=None) -> None:  # no warm workers in-process
        from .runtime import build_agent, run_agent

        self.agent = build_agent(self.spec, self.settings)
        self.task = asyncio.ensure_future(run_agent(self.agent, self.spec))

    @property
    def pid(self) -> int:
        return os.getpid()

    def alive(self) -> bool:
        return self.task is not None and not self.task.done()

    async def wait(self) -> int:
        try:
            self.returncode = await asyncio.shield(self.task)
        except asyncio.CancelledError:
            self.returncode = 143
        except Exception:  # noqa: BLE001 - a crashed in-process agent ends like a crashed process
            self.returncode = 1
        return self.returncode

    async def logged_out(self, timeout: float) -> bool:
        if self.task is not None:
            await asyncio.wait({self.task}, timeout=timeout)
        return self.task is None or self.task.done()

    async def end(self, grace: float = 1.0) -> int | None:
        return await self.stop(grace)  # nothing to tear down after the agent has stopped

    async def stop(self, grace: float = 1.0) -> int | None:
        if self.task is None:
            return None
        if not self.task.done():
            try:
                await asyncio.wait_for(asyncio.shield(self.task), grace)
            except asyncio.TimeoutError:
                self.task.cancel()
                if self.agent.is_alive():
                    await self.agent.stop()
            except Exception:  # noqa: BLE001
                pass
        return await self.wait()

    def stderr_tail(self, n: int = 2000) -> str:
        exc = self.task.exception() if self.task is not None and self.task.done() and not self.task.cancelled() else None
        return f"{type(exc).__name__}: {exc}" if exc else ""

    def last_words(self, n: int = 1500) -> str:
        return self.stderr_tail(n)


SPAWN_MODES = ("process", "inprocess")


def check_spawn_mode(mode: str, what: str = "mode") -> str:
    if mode not in SPAWN_MODES:
        raise ValueError(f"{what} must be 'process' or 'inprocess', not {mode!r}")
    return mode


def spawn_agent(spec: SpawnSpec, workdir: Path, settings, *, mode: str = "process", limits: Limits = Limits(),
                sandbox: Sandbox | None = None, pool=None) -> AgentProcess | InProcessAgent:
    """The one way Dynamic Agents (by the Core) and Cloud Agents (by the Platform) are made from an
    unpacked package in `workdir/package`: a sandboxed process (through an idle warm worker of
    `pool`, agents/warm_pool.py, when there is one), or a task of this process for tests and for
    measuring what the process costs. Not started yet: `await agent.start()`."""
    if check_spawn_mode(mode) == "inprocess":
        return InProcessAgent(spec.name, spec, workdir, settings)
    return AgentProcess(spec.name, spec, workdir, settings, limits, sandbox, pool)


def check_module_names(names) -> tuple[str, ...]:
    names = tuple(names)
    bad = [n for n in names if not all(part.isidentifier() for part in str(n).split("."))]
    if bad:
        raise ValueError(f"not module names: {bad}")
    return names


def _fresh(workdir: Path) -> bool:
    """A run directory a warm worker can take: nothing in it but the unpacked package (a Cloud
    Agent restarted in its old directory starts cold)."""
    try:
        return os.listdir(workdir) == ["package"]
    except OSError:
        return False
