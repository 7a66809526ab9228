"""The XMPP server the agents talk through, and where agents connect (XmppSettings).

The names below are imported on first use: a process that needs only `xmpp_server.compat` (the
benchmark's bare SPADE floor, bench/floor_login.py) does not pay for pydantic and the server
modules (~0.25 s)."""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .probe import LoginError, probe_login
    from .process import EmbeddedServer, ServerStartError
    from .settings import XmppSettings

_WHERE = {"XmppSettings": "settings", "EmbeddedServer": "process", "ServerStartError": "process",
          "LoginError": "probe", "probe_login": "probe"}
__all__ = ["XmppSettings", "EmbeddedServer", "ServerStartError", "LoginError", "probe_login"]


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
