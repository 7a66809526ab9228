"""SPADE's built-in agent web page, switched on by configuration (XmppSettings.web / RAPP_AGENT_WEB):
served on loopback only, URL recorded on the agent and in the trace, gone when the agent stops."""
from __future__ import annotations

import aiohttp
import pytest

from agents.base import RappAgent
from agents.tracing import read_trace
from xmpp_server.settings import XmppSettings


def test_web_setting_from_env():
    assert XmppSettings.from_env({"RAPP_AGENT_WEB": "true"}).web is True
    assert XmppSettings.from_env({}).web is False


async def test_agent_web_page_on_loopback(xmpp_server, trace_file, unique):
    agent = RappAgent(unique("webagent"), xmpp_server.settings(trace_file=trace_file, web=True))
    await agent.start()
    try:
        assert agent.web_url and agent.web_url.startswith("http://127.0.0.1:")
        # bound to loopback only, never to all interfaces
        hosts = {addr[0] for addr in agent.web.runner.addresses}
        assert hosts == {"127.0.0.1"}, hosts
        async with aiohttp.ClientSession() as http:
            async with http.get(agent.web_url) as resp:
                assert resp.status == 200
                page = await resp.text()
        assert agent.address in page
        started = [r for r in read_trace(trace_file) if r["kind"] == "agent"
                   and r["event"] == "started" and r["agent"] == agent.address]
        assert started and started[-1]["web"] == agent.web_url
    finally:
        await agent.stop()
    async with aiohttp.ClientSession() as http:
        with pytest.raises(aiohttp.ClientConnectionError):
            async with http.get(agent.web_url, timeout=aiohttp.ClientTimeout(total=3)):
                pass


async def test_web_off_by_default(settings, unique):
    agent = RappAgent(unique("noweb"), settings)
    await agent.start()
    try:
        assert agent.web_url is None and not agent.web.is_started()
    finally:
        await agent.stop()
