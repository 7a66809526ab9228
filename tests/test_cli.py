"""The `rapp` command line as a user runs it: a subprocess of the installed entry point.

help for every subcommand; package build / keygen / signed build; one-line errors (tracebacks only
with --debug); trace show / export; store publish / list / info / remove and doctor against a
running system (its own embedded server), doctor's FAIL line when nothing listens.
"""
from __future__ import annotations

import asyncio
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ontology.package import SignatureStatus, read_package
from scenarios.system import RappSystem
from xmpp_server.ports import free_port

ROOT = Path(__file__).resolve().parent.parent
FIXTURE = Path(__file__).parent / "fixtures" / "echo_app"
_SCRIPT = Path(sys.executable).with_name("rapp")
RAPP = [str(_SCRIPT)] if _SCRIPT.exists() else [sys.executable, "-m", "cli.main"]


def rapp(*args, env: dict[str, str] | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items() if not k.startswith("RAPP_") or k == "RAPP_TEST_RUN"}  # (the watchdog's mark stays)
    return subprocess.run([*RAPP, *map(str, args)], capture_output=True, text=True, cwd=ROOT,
                          env={**base, **(env or {})}, timeout=timeout, stdin=subprocess.DEVNULL)


async def arapp(*args, **kw) -> subprocess.CompletedProcess:
    """rapp in a thread: the agents under test run on this event loop and must keep running."""
    return await asyncio.to_thread(rapp, *args, **kw)


def one_error_line(res: subprocess.CompletedProcess) -> str:
    assert res.returncode == 1, (res.returncode, res.stdout, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rapp: error: "), res.stderr
    assert "Traceback" not in res.stderr
    return lines[0]


# -- help -------------------------------------------------------------------------------------
def test_top_level_help_lists_every_subcommand():
    res = rapp("--help")
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("usage: rapp")
    for cmd in ("server", "run", "package", "store", "trace", "bench", "doctor", "house"):
        assert cmd in res.stdout


@pytest.mark.parametrize("argv, usage", [
    (["server", "--help"], "usage: rapp server"),
    (["run", "--help"], "usage: rapp run"),
    (["package", "--help"], "usage: rapp package"),
    (["store", "--help"], "usage: rapp store"),
    (["trace", "--help"], "usage: rapp trace show"),
    (["trace", "export", "--help"], "usage: rapp trace export"),
    (["trace", "html", "--help"], "usage: rapp trace html"),
    (["bench", "--help"], "usage: rapp bench"),
    (["doctor", "--help"], "usage: rapp doctor"),
    (["house", "--help"], "usage: rapp house"),
])
def test_subcommand_help(argv, usage):
    res = rapp(*argv)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith(usage), res.stdout[:200]


def test_unknown_subcommand_is_a_usage_error():
    res = rapp("juggle")
    assert res.returncode == 2 and "invalid choice" in res.stderr


# -- package ----------------------------------------------------------------------------------
def test_package_build(tmp_path):
    res = rapp("package", "build", FIXTURE, "-o", tmp_path)
    assert res.returncode == 0, res.stderr
    out = Path(res.stdout.strip())
    assert out == tmp_path / "echo-app-1.0.0.rapp" and out.is_file()
    pkg = read_package(out.read_bytes())
    assert pkg.manifest.name == "echo-app" and pkg.signature is SignatureStatus.UNSIGNED
    assert "echo_app/task.py" in pkg.paths


def test_package_keygen_and_signed_build(tmp_path):
    key = tmp_path / "dev.pem"
    res = rapp("package", "keygen", key)
    assert res.returncode == 0, res.stderr
    assert key.is_file() and (key.stat().st_mode & 0o777) == 0o600
    key_id = res.stdout.strip().rsplit("(id ", 1)[1].rstrip(")")
    res = rapp("package", "build", FIXTURE, "-o", tmp_path / "signed.rapp", "--key", key)
    assert res.returncode == 0, res.stderr
    pkg = read_package((tmp_path / "signed.rapp").read_bytes())
    assert pkg.signed and pkg.key_id == key_id


def test_malformed_manifest_is_one_line_and_debug_shows_traceback(tmp_path):
    src = tmp_path / "bad_app"
    shutil.copytree(FIXTURE, src)
    text = (src / "manifest.yaml").read_text().replace("version: 1.0.0", "version: one point oh")
    (src / "manifest.yaml").write_text(text)
    line = one_error_line(rapp("package", "build", src, "-o", tmp_path))
    assert "version" in line
    res = rapp("--debug", "package", "build", src, "-o", tmp_path)
    assert res.returncode != 0 and "Traceback (most recent call last)" in res.stderr
    assert not list(tmp_path.glob("*.rapp"))


def test_package_build_missing_dir_is_one_line(tmp_path):
    line = one_error_line(rapp("package", "build", tmp_path / "nope"))
    assert "does not exist" in line


# -- against a running system -----------------------------------------------------------------
@pytest.fixture(scope="module")
async def running(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("cli")
    async with RappSystem(workdir, trace_file=workdir / "trace.jsonl") as system:
        env = system.settings.to_env()
        env.pop("RAPP_TRACE_FILE", None)  # the CLI's own client does not write the system trace
        system.env = env
        yield system


async def test_store_publish_list_info_remove(running, tmp_path):
    env = running.env
    pkg = tmp_path / "echo.rapp"
    assert (await arapp("package", "build", FIXTURE, "-o", pkg)).returncode == 0

    res = await arapp("store", "publish", pkg, "--owner", "dev", "--password", "pw", env=env)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("published echo-app 1.0.0")

    res = await arapp("store", "list", env=env)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split()[:2] == ["echo-app", "1.0.0"]

    res = await arapp("store", "info", "echo-app", env=env)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("echo-app 1.0.0 by dev") and "signed by nobody" in res.stdout

    line = one_error_line(await arapp("store", "remove", "echo-app", "--owner", "dev",
                                      "--password", "wrong", env=env))
    assert "RequestRefused" in line or "refuse" in line.lower()

    res = await arapp("store", "remove", "echo-app", "--owner", "dev", "--password", "pw", env=env)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("removed echo-app")

    res = await arapp("store", "list", env=env)
    assert res.returncode == 0 and "echo-app" not in res.stdout
    one_error_line(await arapp("store", "info", "echo-app", env=env))


async def test_trace_show_and_export_mermaid(running, tmp_path):
    pytest.importorskip("scenarios.trace_report",
                        reason="scenarios/trace_report.py (trace views) is not written yet")
    trace = running.settings.trace_file
    # a small conversation of our own, so the trace has messages whatever ran before
    from ontology import store as S
    await running.publisher.request(running.store.address, S.ListPackages(robot_type="nao"))
    assert trace.exists()

    res = await arapp("trace", "show", trace, "--agent", "store")
    assert res.returncode == 0, res.stderr
    assert "  store " in res.stdout and "messages (" in res.stdout.splitlines()[0]  # the summary, by default
    res = await arapp("trace", "show", trace, "--agent", "store", "--view", "table")
    assert res.returncode == 0, res.stderr
    assert "list_packages" in res.stdout

    out = tmp_path / "trace.mmd"
    res = await arapp("trace", "export", trace, "--format", "mermaid", "--agent", "store", "-o", out)
    assert res.returncode == 0, res.stderr
    text = out.read_text()
    assert text.startswith("sequenceDiagram")
    assert "participant" in text and "store" in text and "->>" in text

    res = await arapp("trace", "export", trace, "--format", "mermaid")
    assert res.returncode == 0 and res.stdout.startswith("sequenceDiagram")
    one_error_line(await arapp("trace", "show", tmp_path / "missing.jsonl"))
    run_dir = tmp_path / "run"  # a run's --out folder stands for its trace
    run_dir.mkdir()
    assert "without a trace.jsonl" in one_error_line(await arapp("trace", "show", run_dir))
    (run_dir / "trace.jsonl").write_bytes(trace.read_bytes())
    res = await arapp("trace", "show", run_dir, "--agent", "store")
    assert res.returncode == 0 and "  store " in res.stdout, res.stderr

    # fig. 6 drawn (issue 47.3): the Platform's own FSM s0 -> s1 (its request passes: test_lifecycle.py)
    res = await arapp("trace", "show", trace, "--view", "fsm", "--agent", "platform")
    assert res.returncode == 0, res.stderr
    assert "platform: s0_init -> s1_wait" in res.stdout, res.stdout
    res = await arapp("trace", "export", trace, "--format", "states")
    assert res.returncode == 0 and res.stdout.startswith("stateDiagram-v2"), res.stderr
    assert "_platform__s0_init --> " in res.stdout and "__s1_wait: x1" in res.stdout, res.stdout


async def test_store_serve_serves_the_developers_page_from_the_running_store(running):
    """`rapp store serve` as a developer starts it (the page itself, in headless Chromium:
    tests/test_store_builds.py): the page and the Store's packages and builds as JSON; ended by SIGTERM."""
    import json
    import signal
    import urllib.request

    await running.publish(FIXTURE)
    port = free_port()
    base = {k: v for k, v in os.environ.items() if not k.startswith("RAPP_") or k == "RAPP_TEST_RUN"}
    proc = subprocess.Popen([*RAPP, "store", "serve", "--port", str(port)], cwd=ROOT, env={**base, **running.env},
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)

    def get(path: str) -> bytes:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10) as reply:
            return reply.read()

    try:
        deadline = time.monotonic() + 30.0  # a request that hangs (10 s each) counts against it too
        while True:
            try:
                builds = json.loads(await asyncio.to_thread(get, "/builds.json"))
                break
            except OSError:
                assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
                if time.monotonic() > deadline:
                    raise AssertionError("rapp store serve did not answer within 30 s") from None
                await asyncio.sleep(0.2)
        assert "echo-app" in json.dumps(builds), builds
        assert b"RAPP Store: packages and builds" in await asyncio.to_thread(get, "/")
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(15)


async def test_doctor_reports_running_server_ok(running):
    res = await arapp("doctor", env=running.env)
    s = running.settings
    assert f"ok    configured XMPP server accepts logins: login to {s.host}:{s.port}" in res.stdout, res.stdout


def test_doctor_explains_when_nothing_listens():
    """No server is not a broken install: `rapp run` starts its own (issue: doctor that explains)."""
    port = free_port()
    res = rapp("doctor", env={"RAPP_XMPP_HOST": "127.0.0.1", "RAPP_XMPP_PORT": str(port)})
    assert res.returncode == 0, res.stdout
    assert not [ln for ln in res.stdout.splitlines() if "FAIL" in ln], res.stdout
    note = next(ln for ln in res.stdout.splitlines() if "note" in ln)
    assert "configured XMPP server" in note and f"127.0.0.1:{port}" in note
    assert "rapp run" in note and "rapp server" in note and "RAPP_XMPP_HOST" in note  # the hint
    assert "ok    pinned versions: spade 4.1.4" in res.stdout
    assert "ok    speech recognition: pocketsphinx" in res.stdout
    assert "ok    text to speech: eSpeak NG says 'hello'" in res.stdout  # the test extra includes it
    assert "Traceback" not in res.stdout + res.stderr


def test_doctor_notes_a_missing_speech_extra(monkeypatch, capsys):
    """Without eSpeak NG the install works, minus speech: a note that says what is lost, not a FAIL."""
    from hearing import tts
    from hearing.errors import SpeechUnavailable
    from scenarios import doctor

    def missing(*a, **kw):
        raise SpeechUnavailable("text to speech needs the espeakng-loader package")

    monkeypatch.setattr(tts, "synthesize", missing)
    assert doctor._check("text to speech", doctor._synthesis)
    line = capsys.readouterr().out.strip()
    assert line.startswith("note  text to speech: eSpeak NG is not installed") and "'.[speech]'" in line


def test_a_server_without_db_removes_its_temporary_database_when_it_stops(tmp_path):
    """Each `rapp server` start without --db used to leave a database directory in /tmp."""
    port = free_port()
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "TMPDIR": str(tmp_path)}
    proc = subprocess.Popen([*RAPP, "server", "--port", str(port)], env=env, cwd=ROOT, text=True,
                            stderr=subprocess.PIPE, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL)
    try:
        banner = next(line for line in proc.stderr if line.startswith("embedded XMPP server"))
        assert "removed when it stops" in banner, banner
        db = Path(banner.split("database ")[1].split(",")[0])
        assert proc.stdout.readline().startswith("READY")  # listening: its database is in use
        assert db.exists() and db.parent.parent == tmp_path
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0 and not db.parent.exists(), err


# -- help, trace views and `rapp test` (issue 43 item 7) ---------------------------------------
def test_bench_help_lists_the_benchmarks_it_can_run():
    from bench.runner import BENCHMARKS

    res = rapp("bench", "--help")
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("usage: rapp bench"), res.stdout[:200]
    only = " ".join(res.stdout.split("--only NAME [NAME ...]")[-1].split())  # argparse wraps the help
    assert all(name in only for name in BENCHMARKS), only


HELPS = [[c] for c in ("server", "run", "test", "new", "package", "store", "platform", "house", "say", "trace",
                       "replay", "bench", "agent", "doctor")] + [["trace", "export"], ["trace", "html"]] + [
    ["run", s] for s in ("rapp", "hazard-detection", "hazard-table", "two-robots", "disturbances", "demo")]
_EVERY_HELP = """
import contextlib, io, json, sys
from cli.main import main
out = {}
for argv in json.loads(sys.argv[1]):
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.suppress(SystemExit):
        main([*argv, "--help"])
    out[" ".join(argv)] = buf.getvalue()
print(json.dumps(out))
"""


def options_without_help(text: str) -> list[str]:
    """The arguments of an argparse help text that have no help of their own (on their line or the next)."""
    lines, bare, listed = text.splitlines(), [], False
    for i, line in enumerate(lines):
        if line.endswith(":") and not line.startswith(" "):
            listed = line.startswith(("options", "positional arguments"))
        elif listed and line.startswith("  ") and not line.startswith("   "):
            after = lines[i + 1] if i + 1 < len(lines) else ""
            if "  " not in line.strip() and not (after.startswith("    ") and not after.lstrip().startswith("-")):
                bare.append(line.strip())
    return bare


@pytest.fixture(scope="module")
def every_help() -> tuple[dict[str, str], str]:
    """Each help text of HELPS ("run hazard-detection": its text) and what the process wrote on stderr:
    one process for all (one `rapp ... --help` each took ~5 s of imports)."""
    import json

    res = subprocess.run([sys.executable, "-c", _EVERY_HELP, json.dumps(HELPS)], capture_output=True, text=True,
                         cwd=ROOT, timeout=120, stdin=subprocess.DEVNULL)
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout), res.stderr


def test_every_subcommands_and_scenarios_help_explains_each_argument(every_help):
    helps = every_help[0]
    assert len(helps) == len(HELPS) and all(text.startswith("usage: rapp ") for text in helps.values()), helps
    assert {cmd: bare for cmd, text in helps.items() if (bare := options_without_help(text))} == {}


def test_run_help_lists_every_scenario_and_each_scenarios_help_is_whole(every_help):
    from cli.main import SCENARIOS

    helps, stderr = every_help
    for name in SCENARIOS:
        assert f"\n  {name} " in helps["run"], helps["run"]
    hazard = helps["run hazard-detection"]
    assert "pybullet build time" not in hazard + stderr  # no third-party banner (any help's)
    description = hazard.split("\n\n")[1]
    assert description.rstrip().endswith("scored against ground truth."), description  # not cut mid-sentence
    assert "--quiet" in hazard and "only the closing summary" in hazard
    assert "only the closing summary" in helps["run rapp"]  # one meaning of --quiet




GOLDEN = ROOT / "tests" / "data" / "golden_trace.jsonl"


def test_trace_show_summarises_by_default_limits_and_takes_roles():
    res = rapp("trace", "show", GOLDEN)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines[0].startswith("golden_trace.jsonl: 202 records") and len(lines) < 60, res.stdout
    assert any(line.startswith("  dyn ") and "dyn-nao1-golden-demo-" in line for line in lines), res.stdout  # roles
    res = rapp("trace", "show", GOLDEN, "--view", "table", "--agent", "dyn", "--limit", "5")
    assert res.returncode == 0, res.stderr
    rows = [line for line in res.stdout.splitlines()[2:] if not line.startswith("...")]
    assert len(rows) == 5 and all("dyn-nao1-golden-demo" in row for row in rows), res.stdout
    assert "more records (--limit N" in res.stdout.splitlines()[-1]


def test_rapp_test_runs_a_folders_tests_outside_the_checkout(tmp_path):
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_x.py").write_text(
        "import asyncio\n\nasync def test_async_without_a_mark():\n    await asyncio.sleep(0)\n\n"
        "def test_fails():\n    assert 1 == 2\n")
    res = subprocess.run([*RAPP, "test", str(tmp_path)], capture_output=True, text=True, cwd=tmp_path, timeout=120,
                         stdin=subprocess.DEVNULL)
    assert res.returncode == 1 and "1 failed, 1 passed" in res.stdout, res.stdout[-2000:]
    assert "warning" not in res.stdout.lower(), res.stdout[-2000:]


@pytest.mark.parametrize("example, tests", [("door_audit", 2), ("lamp_patrol", 2)])
def test_rapp_test_robot_runs_the_examples_tests_for_that_robot_only(example, tests):
    """The Store's build runs a RApp's tests once per robot type (RAPP_ROBOT_TYPE): the closing RApp of issue 43
    ran both robots' full-house audits in each, lamp patrol both robots' full-house patrols."""
    res = rapp("test", ROOT / "rapps" / "examples" / example, "--robot", "elektron", "--collect-only", "-q")
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    collected = [line for line in res.stdout.splitlines() if "::" in line]
    assert len(collected) == tests and all("elektron" in c for c in collected), res.stdout
