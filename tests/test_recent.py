"""What an agent remembers of its peers is bounded, the most recently heard kept."""
import pytest

from agents.base import PEERS_KEPT
from agents.recent import RecentSet


def test_the_least_recent_goes_and_a_member_heard_again_stays():
    peers = RecentSet(3)
    for jid in ("a", "b", "c"):
        peers.add(jid)
    peers.add("a")  # heard again: now the most recent
    peers.add("d")
    assert list(peers) == ["c", "a", "d"] and "b" not in peers and len(peers) == 3
    with pytest.raises(ValueError):
        RecentSet(0)


def test_an_agent_remembers_a_bounded_number_of_peers():
    from agents.base import RappAgent
    from xmpp_server.settings import XmppSettings

    agent = RappAgent("core-x", XmppSettings(), password="pw")
    for n in range(PEERS_KEPT + 100):
        agent._heard_from.add(f"dyn-{n}@localhost")
    assert len(agent._heard_from) == PEERS_KEPT and f"dyn-{PEERS_KEPT + 99}@localhost" in agent._heard_from
