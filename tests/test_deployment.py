"""The deployment route of docs/deployment.md, as a deployer runs it: the server, Store, Platform
and a Core as separate `rapp` processes; the owner a plain slixmpp client (no project code); a
signed RApp published while the Core runs; the Core killed (SIGKILL) in the middle of a task and
restarted under its name; the next task runs to its report; nothing is left in the temporary
directory afterwards."""
from __future__ import annotations

import asyncio
import os
import re
import signal
import ssl
import subprocess
from pathlib import Path

import pytest
import slixmpp
from slixmpp.exceptions import IqError, IqTimeout

from agents.sandbox import available
from xmpp_server.ports import free_port

from scenarios.launch import LoggedProcesses

from .test_cli import RAPP
from .test_lifecycle import variant

ROOT = Path(__file__).resolve().parent.parent
FIXTURE = Path(__file__).parent / "fixtures" / "echo_app"
HAZARD_LINE = re.compile(r"Hazard (\S+) \((?:door|lamp)\): (\w+)")  # as the hazard RApp words its reports
pytestmark = pytest.mark.skipif(not available(), reason="`rapp agent core` runs RApps in the sandbox, "
                                                        "which needs root; CI runs as root")


class Owner(slixmpp.ClientXMPP):
    """What any chat client does: register, log in, send and receive chat messages."""

    def __init__(self, jid: str, password: str):
        super().__init__(jid, password)
        self.ssl_context.check_hostname = False
        self.ssl_context.verify_mode = ssl.CERT_NONE  # the embedded server's self-signed certificate
        self.register_plugin("xep_0077")
        self.register_plugin("xep_0199")
        self.texts: list[str] = []
        self.ready = asyncio.Event()
        self.add_event_handler("register", self._register)
        self.add_event_handler("session_start", self._start)
        self.add_event_handler("message", self._message)

    async def _register(self, _):
        iq = self.Iq()
        iq["type"], iq["register"]["username"], iq["register"]["password"] = "set", self.boundjid.user, self.password
        try:
            await iq.send()
        except (IqError, IqTimeout):
            pass

    def _start(self, _):
        self.send_presence()
        self.ready.set()

    def _message(self, msg):
        if msg["type"] in ("chat", "normal") and msg["body"]:
            self.texts.append(msg["body"])

    async def command(self, to: str, text: str, expect: str, timeout: float = 60.0) -> list[str]:
        start = len(self.texts)
        self.send_message(mto=to, mbody=text, mtype="chat")
        return await self.wait_for(expect, start, timeout)

    async def wait_for(self, expect: str, start: int, timeout: float = 60.0) -> list[str]:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while not any(expect in t for t in self.texts[start:]):
            if loop.time() > deadline:
                raise AssertionError(f"no {expect!r} within {timeout}s; got {self.texts[start:]}")
            await asyncio.sleep(0.05)
        return self.texts[start:]


class Deployment(LoggedProcesses):
    def __init__(self, tmp: Path):
        self.tmp, self.port = tmp, free_port("127.0.0.1")
        (tmp / "tmp").mkdir()
        env = {k: v for k, v in os.environ.items() if not k.startswith("RAPP_") or k == "RAPP_TEST_RUN"}  # (the watchdog's mark stays)
        env.update(RAPP_XMPP_HOST="127.0.0.1", RAPP_XMPP_PORT=str(self.port), RAPP_XMPP_DOMAIN="localhost",
                   XDG_DATA_HOME=str(tmp / "data"), RAPP_CREDENTIALS_DIR=str(tmp / "credentials"),
                   TMPDIR=str(tmp / "tmp"), RAPP_TRACE_FILE=str(tmp / "trace.jsonl"))
        super().__init__(tmp, env, RAPP)

    def run(self, *args: str) -> str:
        res = subprocess.run([*RAPP, *args], cwd=self.tmp, env=self.env, capture_output=True, text=True,
                             timeout=120, stdin=subprocess.DEVNULL)
        assert res.returncode == 0, (args, res.stdout, res.stderr)
        return res.stdout

    async def up(self, robot: str = "nao", *extra: str) -> tuple[list[str], Path, "Owner"]:
        """Server, Store, Platform and a Core (in the small house), a signing key the Core trusts,
        and the owner logged in: (the Core's arguments, the key, the owner)."""
        key = self.tmp / "dev.pem"
        pub = re.search(r"public key (\S+)", self.run("package", "keygen", str(key))).group(1)
        core_args = ["agent", "core", "--robot", robot, "--robot-id", f"{robot}1", "--owner", "alice",
                     "--password", "alice-app-pw", "--trust", pub, "--house", "small", "--seed", "2", *extra]
        self.start("server", "server", "--port", str(self.port), "--db", str(self.tmp / "xmpp.db"))
        await asyncio.sleep(1.0)
        self.start("store", "agent", "store")
        self.start("platform", "agent", "platform")
        await self.wait_log("store", "running")
        await self.wait_log("platform", "running")
        self.start("core", *core_args)
        await self.wait_log("core", "running")
        owner = Owner("alice@localhost", "alice-xmpp-pw")
        owner.connect(host="127.0.0.1", port=self.port)
        await asyncio.wait_for(owner.ready.wait(), 20)
        return core_args, key, owner

    def publish(self, src: Path, key: Path) -> None:
        pkg = self.tmp / f"{src.name}.rapp"
        self.run("package", "build", str(src), "--key", str(key), "-o", str(pkg))
        self.run("store", "publish", str(pkg), "--owner", "dev", "--password", "dev-pw")


@pytest.mark.slow  # 130 s: the hazard run itself is in the default suite (test_hazard_scenario), the deployment too (a Core crash)
async def test_deployment_runs_hazard_detection_for_a_plain_chat_owner(tmp_path):
    """The route of docs/deployment.md end to end: `rapp agent core --house small` uploads the
    home description and map for its owner; the owner, a plain XMPP client, asks in words and
    reads every hazard's report in the chat."""
    d = Deployment(tmp_path)
    owner = None
    rec = tmp_path / "recording"
    try:  # simulated as fast as the machine goes, and recorded (docs/recordings.md)
        _, key, owner = await d.up("nao", "--rtf", "0", "--record", str(rec))
        d.publish(ROOT / "rapps" / "hazard_detection", key)
        texts = await owner.command("core-nao1@localhost", "please check the hazards", "hazard-detection finished",
                                    timeout=240)
        assert texts[0].startswith("Starting hazard-detection"), texts
        reports = {m.group(1): m.group(2) for m in map(HAZARD_LINE.search, texts) if m}
        assert set(reports) == {"d1", "l1"}, texts  # the small house's door and lamp, each reported
        assert all(state in ("open", "closed", "on", "off") for state in reports.values()), reports
        d.procs["core"].send_signal(signal.SIGTERM)  # the Core writes run.mcap as it stops
        await asyncio.to_thread(d.procs["core"].wait, 60)
    finally:
        if owner is not None:
            owner.disconnect()
        d.stop_all()
    assert list((tmp_path / "tmp").iterdir()) == []
    assert (rec / "run.mcap").stat().st_size > 0 and any((rec / "packages").glob("*.rapp"))
    # the Platform, a process of its own, recorded nothing: its answers come from the RApp's side
    res = await asyncio.to_thread(subprocess.run, [*RAPP, "replay", str(rec)], cwd=tmp_path, env=d.env,
                                  capture_output=True, text=True, timeout=180, stdin=subprocess.DEVNULL)
    assert res.returncode == 0 and "no divergence" in res.stdout, res.stdout + res.stderr


async def test_deployment_survives_a_core_crash(tmp_path):
    d = Deployment(tmp_path)
    owner = None
    try:
        core_args, key, owner = await d.up()

        # published while the Core runs: it learns the new RApps on the first command naming them
        lingering = variant(tmp_path, "linger-echo", "lingerecho", behaviour="linger", seconds=30)
        for src in (FIXTURE, lingering):
            d.publish(src, key)
        await owner.command("core-nao1@localhost", "echo", "echo-app finished", timeout=90)

        # the Core dies in the middle of a task: its RApp dies with it; restarted under its name,
        # it deletes the run's leftover account and work directory, and serves the next command
        start = len(owner.texts)
        await owner.command("core-nao1@localhost", "lingerecho", "Starting linger-echo")
        d.procs["core"].send_signal(signal.SIGKILL)
        d.procs["core"].wait()
        work = tmp_path / "data" / "rapp" / "core-nao1" / "work"
        assert any(work.glob("*linger-echo")), "the killed Core left its run directory"
        d.start("core", *core_args)
        await d.wait_log("core", "running")
        texts = await owner.command("core-nao1@localhost", "echo", "echo-app finished", timeout=90)
        assert not any("linger-echo finished" in t for t in owner.texts[start:])
        assert not any(work.glob("*linger-echo")), "the restarted Core swept the crash's run directory"
        assert texts[0].startswith("Starting echo-app")
        ledger = tmp_path / "credentials" / "core-nao1.ephemeral.json"
        assert ledger.exists() and "linger-echo" not in ledger.read_text()
    finally:
        if owner is not None:
            owner.disconnect()
        d.stop_all()
    leftovers = list((tmp_path / "tmp").iterdir())
    assert leftovers == [], leftovers
    assert not any(work.iterdir()), "a clean stop empties the work directory"
