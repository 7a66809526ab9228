"""The Store's per-robot build (paper 000 sec. 6.2: the Store "is responsible for RApp compilation
(if necessary) and packaging. There is a separate virtual machine for each available robot. It is
used as a build server"): a published package's own tests, run once per robot type its manifest
declares, each in a sandbox of its own (agents/sandbox.py, agents/confine.py: namespaces, a fresh
uid, seccomp, rlimits and a control group), with RAPP_ROBOT_TYPE naming the type.

    result = await build_for(package_bytes, "elektron", workdir, sandbox)
    result.state, result.reason, result.log     # passed | failed, why, what the tests printed

A package without tests has nothing to run: its sources are compiled (no code of it runs), and it is
listed for every declared type as "untested" (`StoreRepository(require_tests=True)` refuses it).
The tests run as `rapp test DIR` runs them (`pytest_args`): their own rootdir, no configuration of a
checkout, async tests without marks. Inside the sandbox the whole project is importable (a RApp's
test may run it on the simulated robot: scenarios.run_rapp), there is no network but loopback, and
agents a test starts are not sandboxed again (the build's sandbox holds them all).

`python -m agents.store_build` is the program inside: it confines itself first thing, as the agent
runtime does, before anything of the package is read.
"""
from __future__ import annotations

import asyncio
import dataclasses
import os
import py_compile
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from .process import Limits, exit_future
from .sandbox import APP_DIR, ENV_ALLOWED, PROJECT_PACKAGES, Sandbox, confine, open_run_file

BUILD_PACKAGES = (*PROJECT_PACKAGES, "hearing", "scenarios", "cli")  # what a RApp's tests may import
BUILD_TIMEOUT_S = 600.0
BUILD_LIMITS = Limits(cpu_seconds=900, memory_bytes=8 * 1024**3, processes=512, cpu_cores=1.0)
MAX_LOG = 64 * 1024  # of a build's output kept (its end: where pytest says what failed)


@dataclass
class BuildResult:
    state: str  # "passed", "failed" or "untested" (no tests: compiled only)
    reason: str  # why it failed ("" when it passed)
    log: str


def pytest_args(target: Path) -> list[str]:
    """`rapp test DIR`'s pytest arguments: the folder's tests/ (else the folder), its own rootdir,
    no configuration file, async tests without marks, nothing cached into the folder."""
    tests = target / "tests" if (target / "tests").is_dir() else target
    return [str(tests), "--rootdir", str(target if target.is_dir() else target.parent), "-c", os.devnull,
            "-p", "no:cacheprovider", "-o", "asyncio_mode=auto", "-o", "asyncio_default_fixture_loop_scope=function",
            "-o", "asyncio_default_test_loop_scope=function"]


def has_tests(package_dir: Path) -> bool:
    return any((package_dir / "tests").glob("test*.py"))


def compile_sources(package_dir: Path) -> list[str]:
    """Every .py of the package byte-compiled (to nowhere): the errors, one line each."""
    errors = []
    with tempfile.TemporaryDirectory(prefix="rapp-compile-") as out:
        for i, src in enumerate(sorted(package_dir.rglob("*.py"))):
            try:
                py_compile.compile(str(src), cfile=os.path.join(out, f"{i}.pyc"), doraise=True)
            except py_compile.PyCompileError as e:
                errors.append(f"{src.relative_to(package_dir)}: {e.exc_type_name}: {e.exc_value}")
    return errors


def build_env(robot_type: str) -> dict[str, str]:
    """The build's whole environment: an allow-list, the robot type, a home in the run's directory."""
    env = {k: os.environ[k] for k in ENV_ALLOWED if k in os.environ}
    env.setdefault("PATH", "/usr/local/bin:/usr/bin:/bin")
    tmp = f"{APP_DIR}/tmp"
    env.update(PYTHONPATH=str(Path(__file__).resolve().parent.parent), PYTHONDONTWRITEBYTECODE="1",
               PYTHONNOUSERSITE="1", HOME=tmp, TMPDIR=tmp, MPLCONFIGDIR=tmp, RAPP_CREDENTIALS_DIR=f"{tmp}/credentials",
               RAPP_ROBOT_TYPE=robot_type, RAPP_STORE_BUILD="1", COLUMNS="160",
               RAPP_ALLOW_UNSANDBOXED="1")  # agents a test starts: the build's sandbox holds them
    return env


async def run_tests(package_dir: Path, robot_type: str, workdir: Path, sandbox: Sandbox,
                    limits: Limits = BUILD_LIMITS, timeout_s: float = BUILD_TIMEOUT_S) -> BuildResult:
    """The tests of an unpacked package (`package_dir`, inside `workdir`) for one robot type, in the
    sandbox; never blocks the event loop (a process of its own, its exit watched by a pidfd)."""
    from .cgroups import RunGroup
    from .sandbox import CONFINE_ENV

    workdir = Path(workdir)
    # its own /dev/shm (a directory of the run's, writable): Python's multiprocessing needs one for its
    # locks. Named through the sandbox's working directory (the run's): the sandbox's root is built
    # over /tmp, where a Store's data may be
    (workdir / "shm").mkdir(parents=True, exist_ok=True)
    uid = sandbox.new_uid()
    await asyncio.to_thread(sandbox.prepare, workdir, uid)
    sandbox = dataclasses.replace(sandbox, packages=BUILD_PACKAGES,
                                  extra_binds=(("/proc/self/cwd/shm", "/dev/shm", True),))
    group = None
    if sandbox.enabled:
        try:
            group = RunGroup.create(limits, 0)
        except OSError:
            group = None  # rlimits and the namespaces still hold (said once at start by the sandbox)
    env = build_env(robot_type)
    inside = Path(APP_DIR) if sandbox.enabled else workdir
    env[CONFINE_ENV] = sandbox.confinement(uid, limits, 0, cgroup=group)
    env["RAPP_BUILD_DIR"] = str(inside / package_dir.relative_to(workdir))
    log_path = workdir / "build.log"

    def start() -> subprocess.Popen:
        with open_run_file(log_path, "ab") as log:
            return subprocess.Popen([sys.executable, "-P", "-m", "agents.store_build"], cwd=workdir, env=env,
                                    stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    start_new_session=True)

    proc = await asyncio.to_thread(start)
    done = exit_future(proc, before_reap=lambda: _kill_group(proc.pid))
    try:
        code = await asyncio.wait_for(asyncio.shield(done), timeout_s)
        why = ""
    except asyncio.TimeoutError:
        _kill_group(proc.pid)
        code = await done
        why = f"its tests did not end within {timeout_s:g} s"
    except asyncio.CancelledError:
        _kill_group(proc.pid)
        raise
    finally:
        if group is not None:  # whatever of the build is left (a daemon its tests started) goes with it
            await asyncio.to_thread(group.kill)
            await asyncio.to_thread(group.remove)
    log = await asyncio.to_thread(_read_log, log_path)
    if code == 0:
        return BuildResult("passed", "", log)
    return BuildResult("failed", why or failure_reason(log, code), log)


def _kill_group(pgid: int) -> None:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _read_log(path: Path) -> str:
    """The end of the build's output (written by the RApp's tests: opened without following links)."""
    try:
        with open_run_file(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - MAX_LOG))
            text = f.read().decode(errors="replace")
    except OSError as e:
        return f"(no build log: {e})"
    return text if size <= MAX_LOG else f"... ({size - MAX_LOG} bytes before cut)\n" + text


def failure_reason(log: str, code: int) -> str:
    """Why a type was refused, in one line: the first failing test and its error (pytest's "E" line),
    else the sandbox's or the run's last words."""
    lines = [ln.strip() for ln in log.splitlines() if ln.strip()]
    failed = [ln for ln in lines if ln.startswith(("FAILED ", "ERROR "))]
    if failed:
        test = failed[0].split(" ", 1)[1].split(" - ", 1)[0]
        error = next((ln[1:].strip() for ln in lines if ln.startswith("E ") and "Error" in ln), "")
        error = error or next((ln[1:].strip() for ln in lines if ln.startswith("E ")), "")
        more = f" (and {len(failed) - 1} more)" if len(failed) > 1 else ""
        return f"{test}: {error}"[:400] + more if error else failed[0][:400] + more
    if "rapp sandbox:" in log:
        return next(ln for ln in lines if "rapp sandbox:" in ln)[:400]
    tail = next((ln for ln in reversed(lines) if "Error" in ln or "error" in ln), lines[-1] if lines else "")
    return f"its tests exited with code {code}" + (f": {tail[:300]}" if tail else "")


def main() -> int:
    """Inside the build's sandbox: confine, then run the package's tests as `rapp test` does."""
    confine()  # first: before anything of the package is read
    os.makedirs(os.environ.get("TMPDIR", "/tmp"), exist_ok=True)
    import pytest

    target = Path(os.environ["RAPP_BUILD_DIR"])
    print(f"rapp store build: {target.name} for robot type {os.environ.get('RAPP_ROBOT_TYPE')}", flush=True)
    return int(pytest.main([*pytest_args(target), "-q"]))


if __name__ == "__main__":
    sys.exit(main())
