"""Ends what a test run started once the run is gone, even when it was killed (SIGKILL, a CI timeout).

    python tests/run_watchdog.py PID MARK

Started by tests/conftest.py in a session of its own (a kill of the run's process group misses it),
it waits for process PID (pytest's controller) to end, then kills every process whose environment
holds RAPP_TEST_RUN=MARK (every server, agent and worker the run started inherits it), scanning again
until none is left, and removes the RApp sandboxes' control groups their dead creators left
(agents/cgroups.py sweep). A killed CI run had left `rapp server` and `rapp agent` processes running
for over ten minutes."""
import os
import select
import signal
import sys
import time


def marked(mark: bytes) -> list[int]:
    out = []
    for entry in os.scandir("/proc"):
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                with open(f"{entry.path}/environ", "rb") as f:
                    if mark in f.read().split(b"\0"):
                        out.append(int(entry.name))
            except OSError:
                pass
    return out


def main(pid: int, mark: str) -> None:
    try:
        fd = os.pidfd_open(pid)
        select.select([fd], [], [])
    except (OSError, AttributeError):
        while os.path.exists(f"/proc/{pid}"):
            time.sleep(0.5)
    needle = f"RAPP_TEST_RUN={mark}".encode()
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        found = marked(needle)
        if not found:
            break
        for p in found:
            try:
                os.kill(p, signal.SIGKILL)
            except OSError:
                pass
        time.sleep(0.1)
    try:
        sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        from agents.cgroups import sweep
        sweep()
    except Exception:  # noqa: BLE001 - best effort: no control groups here
        pass


if __name__ == "__main__":
    main(int(sys.argv[1]), sys.argv[2])
