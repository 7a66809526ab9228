"""The SDK's CloudProxy while the Platform restarts its Cloud Agent: calls wait for the Platform's
word, and a restart it never reports (no word within CLOUD_RESTART_WAIT_S) leaves the Cloud Agent
lost for this call and every later one, without a second wait."""
import asyncio
import time

import pytest

import rapps.sdk as sdk
from agents.errors import CloudAgentLost


class NoAgent:
    async def request(self, *a, **kw):  # never reached: the proxy refuses before it sends
        raise AssertionError("a call went out to a lost Cloud Agent")


async def test_a_restart_never_reported_leaves_it_lost_once(monkeypatch):
    monkeypatch.setattr(sdk, "CLOUD_RESTART_WAIT_S", 0.2)
    proxy = sdk.CloudProxy(NoAgent(), "platform@localhost", "t", "app", "1.0", "ont")
    proxy.address = "cloud@localhost"
    proxy.told("exited with code -11", restarting=True)
    t0 = time.monotonic()
    with pytest.raises(CloudAgentLost, match="no word from the Platform"):
        await proxy.call("double", value=1)
    assert time.monotonic() - t0 >= 0.2
    t1 = time.monotonic()
    with pytest.raises(CloudAgentLost):
        await proxy.call("double", value=1)
    assert time.monotonic() - t1 < 0.1  # no second wait


async def test_calls_made_while_it_restarts_go_out_once_it_serves():
    sent = []

    class Agent:
        async def request(self, to, content, timeout=None):
            sent.append(to)
            return "answer"

    proxy = sdk.CloudProxy(Agent(), "platform@localhost", "t", "app", "1.0", "platform")
    proxy.address = "cloud@localhost"
    proxy.told("exited", restarting=True)
    call = asyncio.ensure_future(proxy.call("ping"))
    await asyncio.sleep(0.05)
    assert not call.done() and sent == []
    proxy.told("exited", restarted=True)
    assert await call == "answer" and sent == ["cloud@localhost"]
