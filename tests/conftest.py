"""Shared fixtures: one real embedded XMPP server per test session, on free loopback ports."""
from __future__ import annotations

import pytest

from xmpp_server import EmbeddedServer


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

