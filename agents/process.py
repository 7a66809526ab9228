"""Child processes for Dynamic and Cloud Agents (the paper's fork-exec), always reaped.

Each child runs in its own session (so the whole group can be killed), its own working directory,
with CPU-time and memory limits, stdout/stderr to files in that directory. `stop()` sends SIGTERM,
then SIGKILL after a grace period, then waits: no zombie is ever left behind.
"""
from __future__ import annotations

import asyncio
import os
import resource
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path


def exit_future(proc: subprocess.Popen) -> asyncio.Future:
    """Resolves with the process's return code when it exits. The loop watches a pidfd; a thread
    blocked in `proc.wait()` would hold one of the loop's default executor's few workers for the
    process's whole life (20 running Dynamic Agents starved every `to_thread` call of the Platform
    in the same process). Without pidfds (not Linux), a daemon thread of its own waits."""
    loop = asyncio.get_running_loop()
    fut = loop.create_future()

    def resolve(code: int) -> None:
        if not fut.done():
            fut.set_result(code)

    try:
        fd = os.pidfd_open(proc.pid)
    except (AttributeError, OSError):
        threading.Thread(target=lambda: loop.call_soon_threadsafe(resolve, proc.wait()),
                         name=f"wait-{proc.pid}", daemon=True).start()
        return fut

    def exited() -> None:
        loop.remove_reader(fd)
        os.close(fd)
        resolve(proc.wait())  # already exited: reaps at once

    loop.add_reader(fd, exited)
    return fut


@dataclass(frozen=True)
class Limits:
    cpu_seconds: int | None = 600
    memory_bytes: int | None = 2 * 1024**3
    open_files: int | None = 1024

    def apply(self) -> None:  # runs in the child between fork and exec
        if self.cpu_seconds:
            resource.setrlimit(resource.RLIMIT_CPU, (self.cpu_seconds, self.cpu_seconds + 5))
        if self.memory_bytes:
            resource.setrlimit(resource.RLIMIT_AS, (self.memory_bytes, self.memory_bytes))
        if self.open_files:
            resource.setrlimit(resource.RLIMIT_NOFILE, (self.open_files, self.open_files))


def project_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    """The parent's environment, with this project importable and `extra` on top."""
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parent.parent)
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.update(extra or {})
    return env


class AgentProcess:
    def __init__(self, name: str, module: str, args: list[str], workdir: Path,
                 env: dict[str, str] | None = None, limits: Limits = Limits()):
        self.name = name
        self.argv = [sys.executable, "-m", module, *args]
        self.workdir = Path(workdir)
        self.env = project_env(env)
        self.limits = limits
        self.proc: subprocess.Popen | None = None
        self._waiter: asyncio.Future | None = None
        self.returncode: int | None = None

    async def start(self) -> None:
        # Popen + a waiting thread, not asyncio subprocesses: SPADE installs uvloop's loop policy,
        # whose child watcher the standard loop cannot use.
        self.workdir.mkdir(parents=True, exist_ok=True)
        out = open(self.workdir / "stdout.log", "ab")
        err = open(self.workdir / "stderr.log", "ab")
        try:
            self.proc = await asyncio.to_thread(
                subprocess.Popen, self.argv, cwd=self.workdir, env=self.env, stdout=out, stderr=err,
                stdin=subprocess.DEVNULL, start_new_session=True, preexec_fn=self.limits.apply)
        finally:
            out.close()
            err.close()
        self._waiter = exit_future(self.proc)

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc else None

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    async def wait(self) -> int:
        assert self._waiter is not None
        self.returncode = await asyncio.shield(self._waiter)
        return self.returncode

    async def stop(self, grace: float = 1.0) -> int | None:
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self._signal(signal.SIGTERM)
            try:
                await asyncio.wait_for(self.wait(), grace)
            except asyncio.TimeoutError:
                self._signal(signal.SIGKILL)
        self._signal(signal.SIGKILL)  # leftovers in the group (grandchildren)
        return await self.wait()

    def _signal(self, sig: int) -> None:
        try:
            os.killpg(self.proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

    def stderr_tail(self, n: int = 2000) -> str:
        try:
            return (self.workdir / "stderr.log").read_text(errors="replace")[-n:]
        except OSError:
            return ""


class InProcessAgent:
    """The AgentProcess interface for an agent run as a task of this process: the same package
    bytes, unpacking and runtime code, no isolation (no limits, a crash affects the caller).
    For fast tests and for measuring what the process costs."""

    def __init__(self, name: str, spec: dict, workdir: Path, settings):
        self.name, self.spec, self.workdir, self.settings = name, spec, Path(workdir), settings
        self.task: asyncio.Task | None = None
        self.agent = None
        self.returncode: int | None = None

    async def start(self) -> None:
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
