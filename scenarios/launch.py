"""Commands started as a deployer starts them (`rapp server`, `rapp agent store|platform|core`): each
in a session of its own, its output in `<directory>/<name>.log`; wait for a line of that log; stop
them all. Used by the fleet benchmark (its Store and Platform) and the deployment tests."""
from __future__ import annotations

import asyncio
import signal
import subprocess
from pathlib import Path

from xmpp_server.process import dies_with_parent, signal_group, terminate


class LoggedProcesses:
    def __init__(self, directory: Path, env: dict, argv: list[str], *, die_with_parent: bool = False):
        self.directory, self.env, self.argv = Path(directory), env, list(argv)
        self.die_with_parent = die_with_parent  # SIGTERM when the starting thread ends (dies_with_parent)
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, *args: str) -> subprocess.Popen:
        with open(self.directory / f"{name}.log", "ab") as log:  # the child keeps its own copy
            proc = subprocess.Popen([*self.argv, *args], cwd=self.directory, env=self.env, stdout=log,
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True,
                                    preexec_fn=dies_with_parent() if self.die_with_parent else None)
        self.procs[name] = proc
        return proc

    def log(self, name: str) -> str:
        return (self.directory / f"{name}.log").read_text(errors="replace")

    async def wait_log(self, name: str, text: str, timeout: float = 60.0) -> None:
        """Until `text` is in the log of `name`; AssertionError with the log's end if it exits or
        `timeout` s pass first."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while text not in self.log(name):
            if self.procs[name].poll() is not None or loop.time() > deadline:
                raise AssertionError(f"{name}: no {text!r}: {self.log(name)[-2000:]}")
            await asyncio.sleep(0.1)

    def stop_all(self, timeout: float = 15.0) -> None:
        """SIGTERM to every process group, the last started first; then each waited for, SIGKILLed
        after `timeout` s (and whatever is left of its group); never a zombie."""
        for proc in reversed(list(self.procs.values())):
            if proc.poll() is None:
                signal_group(proc, signal.SIGTERM)
        for proc in reversed(list(self.procs.values())):
            terminate(proc, timeout)
