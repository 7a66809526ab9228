"""SPADE's XMPP client with a shared TLS context when certificates are not verified, and message
data forms left as XML.

slixmpp builds a fresh default SSL context for every client and loads the system CA store into it
twice (``create_default_context`` + ``set_default_verify_paths``): ~75 ms of every login, i.e. most
of an in-process Dynamic Agent's hand-off, spent on certificates that are never checked on loopback.
With ``verify_security`` off every client shares one context without CA paths; with it on, nothing
changes. The body repeats ``spade.xmpp_client.XMPPClient.__init__`` of spade 4.1.4 (pinned) with the
context passed through; revisit on any SPADE upgrade (docs/spade-pitfalls.md).
"""
from __future__ import annotations

import logging

from slixmpp import ClientXMPP, __version__
from spade.xmpp_client import XMPPClient

from xmpp_server.tls import unverified_context


class RappXMPPClient(XMPPClient):
    def __init__(self, jid, password, verify_security, auto_register):
        if verify_security:
            super().__init__(jid, password, verify_security, auto_register)
        else:
            self._init_unverified(jid, password, auto_register)
        drop_message_forms(self)

    def _init_unverified(self, jid, password, auto_register):
        from packaging import version

        ClientXMPP.__init__(self, jid, password, ssl_context=unverified_context())
        self.logger = logging.getLogger("spade.Agent")
        if version.parse(__version__) >= version.Version("1.10.0"):
            self.enable_direct_tls = False
        self.add_event_handler("session_start", self.session_start)
        self.register_plugin("xep_0199")
        if auto_register:
            self.add_event_handler("register", self.register)
            self.register_plugin("xep_0077")
        self["xep_0199"].enable_keepalive(interval=55)
        self.register_plugin("xep_0363")

    def session_start(self, event):
        # SPADE's session_start leaves the roster request's future unretrieved: an agent stopped
        # (or a server gone) before the answer printed "Future exception was never retrieved"
        self.send_presence()
        self.get_roster().add_done_callback(lambda f: f.cancelled() or f.exception())


def install() -> None:
    """Make SPADE agents in this process build their clients with RappXMPPClient."""
    import spade.agent

    from xmpp_server.client_cleanup import remove_upload_dir_at_exit

    spade.agent.XMPPClient = RappXMPPClient
    remove_upload_dir_at_exit()


def drop_message_forms(client: ClientXMPP) -> None:
    """Leave a message's data form as raw XML. Once any plugin loads XEP-0004 (in-band registration
    does), slixmpp turns the form of every incoming message into stanza objects, one per field:
    ~200 us per ACL message, whose metadata SPADE's Message.from_node then reads from the raw XML
    anyway. The registration is class-wide: it is undone here and kept from coming back when any
    other client of the process (a chat user, a benchmark's floor client) loads XEP-0004 later."""
    from slixmpp.stanza import Message

    _keep_forms_off_messages()
    client.remove_handler("Data Form")
    Message.plugin_tag_map.pop("{jabber:x:data}x", None)
    Message.plugin_attrib_map.pop("form", None)


def _keep_forms_off_messages() -> None:
    from slixmpp.plugins.xep_0004 import dataforms
    from slixmpp.plugins.xep_0004.stanza import Form
    from slixmpp.stanza import Message

    register = dataforms.register_stanza_plugin
    if getattr(register, "keeps_forms_off_messages", False):
        return

    def register_except_message_forms(stanza, plugin, *args, **kwargs):
        if not (stanza is Message and plugin is Form):
            register(stanza, plugin, *args, **kwargs)

    register_except_message_forms.keeps_forms_off_messages = True
    dataforms.register_stanza_plugin = register_except_message_forms

