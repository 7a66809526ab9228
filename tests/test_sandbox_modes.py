"""The rootless sandbox (user namespaces) refuses what the root one refuses (issue 41, item 8).

tests/sandbox/battery.py runs one sandboxed process that tries what a RApp must not do (read a
secret, write outside /app, forbidden system calls, another loopback port, an abstract Unix socket,
a second XMPP connection, more processes than its limit, a forking chain that should outlive it),
once as root and once as an unprivileged user: each attempt must end the same way, and each
refusal must be told to its parent the same way. Real processes, real namespaces, no server needed
(a listener stands for it)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from agents.sandbox import probe

HERE = Path(__file__).parent / "sandbox"
ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.skipif(os.geteuid() != 0 or probe().mode != "root",
                                reason="runs the battery as root and as an unprivileged user: needs root")


def _battery(tmp_path: Path, as_nobody: bool) -> dict:
    out, work = tmp_path / f"{as_nobody}.json", tmp_path / f"work-{as_nobody}"
    secret = tmp_path / "secret"
    secret.write_text("root's secret")
    secret.chmod(0o600)
    cmd = [sys.executable, str(HERE / "battery.py"), str(out), str(work), str(secret)]
    if as_nobody:
        tmp_path.chmod(0o777)  # the user's own run directory and result
        cmd = [sys.executable, str(HERE / "as_nobody.py"), f"{os.path.realpath(sys.base_prefix)}:{ROOT}:{tmp_path}",
               *cmd]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=ROOT,
                         env={**os.environ, "HOME": str(tmp_path)})
    assert run.returncode == 0 and out.exists(), run.stderr[-3000:]
    return json.loads(out.read_text())


def test_the_rootless_sandbox_refuses_what_the_root_one_refuses(tmp_path):
    root, user = _battery(tmp_path, False), _battery(tmp_path, True)
    assert (root["mode"], user["mode"]) == ("root", "user"), (root, user)
    for result in (root, user):
        assert not result["uid_is_root"] and result["cwd"] == "/app" and not result["proc"], result
        assert result["read_secret"] == "ERR" and set(result["writes"].values()) == {"ERR"}, result
        assert result["own_write"] == "done" and result["xmpp"] == "hello", result
        assert set(result["syscalls"].values()) == {"Operation not permitted"}, result
        assert (result["other_port"], result["abstract"], result["interfaces"]) == ("ERR", "ERR", ["lo"]), result
        assert (result["second_xmpp"], result["fork_limit"], result["left_behind"]) == ("closed", "held", 0), result
        assert result["exit_code"] == 0, result
    same = {k for k in root if k not in ("mode", "refused_told")}
    assert {k: root[k] for k in same} == {k: user[k] for k in same}
    # told alike; root's control group also counts the process limit's refusals (no group without root here)
    cgroup_only = {"a new process (its process limit)"}
    assert set(root["refused_told"]) - cgroup_only == set(user["refused_told"]), (root["refused_told"], user["refused_told"])
    assert {"system call ptrace", "system call mount", "system call unshare", "system call bpf",
            "a second XMPP connection"} <= set(user["refused_told"])
