"""xmpp_server/compat.py: the patches of SPADE, slixmpp and pyjabber internals are installed by one
call that checks the pinned versions first."""
from __future__ import annotations

import pytest

from xmpp_server import compat


def test_installed_versions_match_the_pins():
    assert compat.check_pins() == compat.PINS


def test_another_version_is_refused_with_a_clear_message(monkeypatch):
    monkeypatch.setitem(compat.PINS, "spade", "9.9.9")
    with pytest.raises(compat.PinMismatch, match=r"spade 4\.1\.4 is installed but 9\.9\.9 is pinned.*pip install"):
        compat.check_pins("spade")
    monkeypatch.setitem(compat.PINS, "no-such-dist", "1.0")
    with pytest.raises(compat.PinMismatch, match="no-such-dist is not installed"):
        compat.check_pins("no-such-dist")


def test_agent_patches_are_installed_once_and_checked(monkeypatch):
    import spade.agent
    from spade.behaviour import CyclicBehaviour

    compat.install_agent_patches()
    assert CyclicBehaviour._step is compat._cancellable_step
    assert spade.agent.XMPPClient is compat.rapp_xmpp_client_class()
    compat.install_agent_patches()  # idempotent
    assert spade.agent.XMPPClient is compat.rapp_xmpp_client_class()
    monkeypatch.setattr(compat, "_installed", set())
    monkeypatch.setitem(compat.PINS, "pyjabber", "0.0.1")
    with pytest.raises(compat.PinMismatch):  # a mismatch stops before anything is patched again
        compat.install_agent_patches()
