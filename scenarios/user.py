"""The robot owner's chat client lives in xmpp_server/chat.py (RApps such as the rtt probe use it
too, and a RApp's sandbox holds no scenarios); this name stays for existing imports."""
from xmpp_server.chat import KEEPALIVE_S, ChatUser

__all__ = ["ChatUser", "KEEPALIVE_S"]
