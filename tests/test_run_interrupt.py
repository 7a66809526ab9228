"""Ctrl-C (SIGINT to the command's process group, as a terminal sends it) or SIGTERM on a `rapp run`:
the run stops, result.json (`ok: false`, the reason, what the RApp reported so far, the truth), the
plot, the chat and the trace are written, the command exits 128 + the signal, and every process of
the run has ended. A real `rapp run rapp` subprocess with a RApp that waits."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from .test_cli import RAPP, ROOT

FIXTURE = Path(__file__).parent / "fixtures" / "echo_app"


def waiting_rapp(tmp_path: Path) -> Path:
    """The echo RApp, reporting "subscribed" and then waiting up to two minutes for events."""
    dest = tmp_path / "echo-wait"
    shutil.copytree(FIXTURE, dest)
    manifest = yaml.safe_load((dest / "manifest.yaml").read_text())
    manifest.update(name="echo-wait", keywords=["echowait"], time_limit_s=300)
    manifest["params"]["behaviour"] = "events"
    (dest / "manifest.yaml").write_text(yaml.safe_dump(manifest))
    return dest


def reported(trace: Path) -> bool:
    """The Core has taken the RApp's first report."""
    if not trace.exists():
        return False
    lines = trace.read_text().splitlines()[:-1]  # the last may be half written
    return any(r.get("action") == "report" and r.get("dir") == "recv" for r in map(json.loads, lines))


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie has ended (its parent may not have reaped it yet)
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False


@pytest.mark.timeout(240)
@pytest.mark.parametrize("sig", [signal.SIGINT, pytest.param(signal.SIGTERM, marks=pytest.mark.slow)],
                         ids=["SIGINT", "SIGTERM"])
def test_an_interrupted_run_writes_its_result_and_ends_every_process(tmp_path, sig):
    out = tmp_path / "out"
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAPP_") or k == "RAPP_TEST_RUN"}  # (the watchdog's mark stays)
    with open(tmp_path / "log.txt", "w") as log:
        proc = subprocess.Popen([*RAPP, "run", "rapp", waiting_rapp(tmp_path), "--robot", "nao", "--house", "small",
                                 "--out", out, "--plain"], cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 150
        trace = out / "trace.jsonl"
        while not reported(trace):
            assert proc.poll() is None and time.monotonic() < deadline, (tmp_path / "log.txt").read_text()[-3000:]
            time.sleep(0.3)
        pids = {json.loads(line)["pid"] for line in trace.read_text().splitlines()}  # every process that traced
        if sig == signal.SIGINT:
            os.killpg(proc.pid, sig)  # a terminal's Ctrl-C: the whole foreground group
        else:
            proc.send_signal(sig)
        code = proc.wait(90)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    text = (tmp_path / "log.txt").read_text()
    assert code == 128 + sig, text[-3000:]
    assert f"{sig.name}: stopping the run" in text and "Traceback" not in text, text[-3000:]
    result = json.loads((out / "result.json").read_text())
    assert result["ok"] is False and result["reason"].startswith(f"interrupted by {sig.name}"), result["reason"]
    assert [r["text"] for r in result["reports"]] == ["subscribed"]  # what was known
    assert result["truth"]["doors"] and result["truth"]["trajectory"]
    assert (out / "run.png").read_bytes()[:4] == b"\x89PNG" and (out / "chat.txt").read_text().strip()
    wrote = next((line.split(f"wrote in {out}: ", 1)[1] for line in text.splitlines() if f"wrote in {out}: " in line), "")
    assert {"chat.txt", "result.json", "run.png", "trace.jsonl", "run.mcap"} <= set(wrote.split(", ")), text[-3000:]
    deadline = time.monotonic() + 10
    while (group_alive(proc.pid) or any(alive(p) for p in pids)) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not group_alive(proc.pid), "a process of the run's group is still running"
    assert not [p for p in pids if alive(p)], "an agent process of the run is still running"


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_an_interrupted_hazard_table_keeps_the_runs_so_far(tmp_path):
    """Ctrl-C during a table's run: that run's result.json is written, table.json holds it (cut short,
    `ok: false`), the command exits 130 and no process of the table is left."""
    out = tmp_path / "table"
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAPP_") or k == "RAPP_TEST_RUN"}  # (the watchdog's mark stays)
    with open(tmp_path / "log.txt", "w") as log:
        proc = subprocess.Popen([*RAPP, "run", "hazard-table", "--robots", "nao", "--house", "small",
                                 "--seed-list", "small:1", "small:2", "--out", out], cwd=ROOT, env=env, stdout=log,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 200
        trace = out / "nao-small-1" / "trace.jsonl"
        while not reported(trace):
            assert proc.poll() is None and time.monotonic() < deadline, (tmp_path / "log.txt").read_text()[-3000:]
            time.sleep(0.3)
        os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(90)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    text = (tmp_path / "log.txt").read_text()
    assert code == 130 and "interrupted" in text and "Traceback" not in text, text[-3000:]
    table = json.loads((out / "table.json").read_text())
    assert [(r["house"], r["seed"], r["ok"]) for r in table] == [("small", 1, False)], table
    assert json.loads((out / "nao-small-1" / "result.json").read_text())["reason"].startswith("interrupted by SIGINT")
    assert not (out / "nao-small-2").exists()  # the table stopped
    deadline = time.monotonic() + 10
    while group_alive(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not group_alive(proc.pid), "a process of the table is still running"
