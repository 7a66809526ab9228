"""A killed test run leaves no server or agent behind (issue 41, item 1): tests/run_watchdog.py."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# a server that takes its time over SIGTERM (the parent-death signal the suite's launchers arm) and
# leads a session of its own (a kill of the run's process group misses it): what a killed CI run left
INNER = '''
import subprocess, sys, time
from xmpp_server.process import dies_with_parent

SLOW = "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); time.sleep(300)"

def test_starts_a_server_and_is_killed(tmp_path):
    server = subprocess.Popen([sys.executable, "-c", SLOW], start_new_session=True, preexec_fn=dies_with_parent())
    (tmp_path.parent.parent / "server.pid").write_text(str(server.pid))
    time.sleep(300)
'''


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_a_killed_run_leaves_no_server_behind(tmp_path):
    (tmp_path / "test_inner.py").write_text(INNER)
    env = {k: v for k, v in os.environ.items() if k != "RAPP_TEST_RUN"}
    run = subprocess.Popen([sys.executable, "-m", "pytest", "-q", "-p", "tests.conftest", "-p", "no:cacheprovider",
                            "-c", os.devnull, "--rootdir", str(tmp_path), "--basetemp", str(tmp_path / "base"),
                            str(tmp_path / "test_inner.py")], cwd=ROOT, env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    pid_file = tmp_path / "server.pid"
    deadline = time.monotonic() + 60
    while not pid_file.exists() and time.monotonic() < deadline and run.poll() is None:
        time.sleep(0.1)
    assert pid_file.exists(), "the inner run did not start its server"
    server = int(pid_file.read_text())
    assert _alive(server)
    os.killpg(run.pid, signal.SIGKILL)  # as a CI timeout would: nothing of pytest runs after this
    run.wait()
    deadline = time.monotonic() + 15
    while _alive(server) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(server), "the killed run's server still runs"
