"""The XMPP server the agents talk through, and where agents connect (XmppSettings)."""
from .settings import XmppSettings
from .process import EmbeddedServer, ServerStartError
from .probe import LoginError, probe_login

__all__ = ["XmppSettings", "EmbeddedServer", "ServerStartError", "LoginError", "probe_login"]
