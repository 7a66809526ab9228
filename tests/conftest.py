"""Shared fixtures: one real embedded XMPP server per test session, on free loopback ports; and a
watchdog that ends what the run started when the run ends, even killed (tests/run_watchdog.py)."""
from __future__ import annotations

import os
import secrets
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from xmpp_server import EmbeddedServer


def pytest_configure(config):
    """In the run's controller (not an xdist worker): every process the run starts inherits
    RAPP_TEST_RUN; a watchdog in a session of its own kills them all once the controller is gone."""
    if hasattr(config, "workerinput") or os.environ.get("RAPP_TEST_RUN") or not sys.platform.startswith("linux"):
        return
    mark = secrets.token_hex(8)
    env = {k: v for k, v in os.environ.items() if k != "RAPP_TEST_RUN"}
    subprocess.Popen([sys.executable, str(Path(__file__).parent / "run_watchdog.py"), str(os.getpid()), mark],
                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                     start_new_session=True, env=env)
    os.environ["RAPP_TEST_RUN"] = mark


@pytest.fixture(scope="session", autouse=True)
def credentials_dir(tmp_path_factory):
    """Agents' password files of this test session (never the user's ~/.local/share/rapp)."""
    import os

    path = tmp_path_factory.mktemp("credentials")
    old = os.environ.get("RAPP_CREDENTIALS_DIR")
    os.environ["RAPP_CREDENTIALS_DIR"] = str(path)
    yield path
    if old is None:
        os.environ.pop("RAPP_CREDENTIALS_DIR", None)
    else:
        os.environ["RAPP_CREDENTIALS_DIR"] = old


@pytest.fixture(scope="session")
async def xmpp_server():
    async with EmbeddedServer() as server:
        yield server


@pytest.fixture
def trace_file(tmp_path):
    return tmp_path / "trace.jsonl"


@pytest.fixture
def settings(xmpp_server, trace_file):
    return xmpp_server.settings(trace_file=trace_file)


_counter = 0


@pytest.fixture
def unique():
    """Unique agent names per test (accounts persist for the whole server session)."""
    def make(prefix: str) -> str:
        global _counter
        _counter += 1
        return f"{prefix}{_counter}"
    return make


# -- a page in a real headless browser (the trace viewer, the recording's scene) ----------------
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


@pytest.fixture
def browser_page():
    sync_api = pytest.importorskip("playwright.sync_api",
                                   reason="pip package 'playwright' is not installed")
    exe = CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium")
    if not exe:
        pytest.skip("Debian package 'chromium' is not installed (no /usr/bin/chromium)")
    with sync_api.sync_playwright() as pw:
        try:
            browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS, timeout=15000)
        except Exception as e:  # noqa: BLE001 - a broken browser install is an environment issue
            pytest.skip(f"chromium at {exe} does not start under playwright: {e}")
        page = browser.new_page(viewport={"width": 1500, "height": 900})
        page.set_default_timeout(5000)
        page.problems = []
        page.on("console", lambda m: m.type == "error" and page.problems.append(m.text))
        page.on("pageerror", lambda e: page.problems.append(str(e)))
        page.route("**/*", lambda route: route.abort() if not route.request.url.startswith("file:")
                   else route.continue_())  # offline: anything remote would fail loudly
        try:
            yield page
        finally:
            browser.close()
