"""Every patch of a third-party internal (SPADE, slixmpp, pyjabber), in one module, installed by one
explicit call that first checks the installed versions against the pins:

    install_agent_patches()    AgentDoor.__init__, i.e. RappAgent's (every agent process)
    install_server_patches()   xmpp_server.embedded.build_server (the embedded server process)

and every override of, or read from, their private members:

    AgentDoor         spade.agent.Agent's _async_connect, _message_received and container (mixin)
    ConnectsTo        spade.agent.Agent's _async_connect alone (the benchmark's bare SPADE floor)
    metadata_of       spade.message.Message._metadata (no public mapping in 4.1.4)
    end_filter_task   slixmpp's XMLStream._run_out_filters
    configure_server  pyjabber's Server._http_server and _host

Each names the upstream code it replaces; docs/spade-pitfalls.md lists them. A version other than
the pinned one fails with PinMismatch: the patches repeat pinned upstream code. ruff's SLF001
(private member access) is off for this module only (pyproject.toml): a reach-in anywhere else
fails the lint.
"""
from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import operator
from importlib.metadata import PackageNotFoundError, version
from typing import Any, Callable

_log = logging.getLogger("rapp.compat")
PINS = {"spade": "4.1.4", "pyjabber": "0.4.5", "slixmpp-multiplatform": "1.12.0"}


class PinMismatch(RuntimeError):
    pass


def check_pins(*dists: str) -> dict[str, str]:
    """The installed versions of `dists` (all pins when none given); PinMismatch unless pinned."""
    found = {}
    for dist in dists or tuple(PINS):
        try:
            found[dist] = version(dist)
        except PackageNotFoundError:
            raise PinMismatch(f"{dist} is not installed ({PINS[dist]} is pinned): pip install -e .") from None
        if found[dist] != PINS[dist]:
            raise PinMismatch(f"{dist} {found[dist]} is installed but {PINS[dist]} is pinned, and "
                              f"xmpp_server/compat.py patches that version's internals: pip install -e .")
    return found


_installed: set[str] = set()
_checked: set[str] = set()


def _check_once(*dists: str) -> None:
    """check_pins, once per process and distribution (agents are built many times in one)."""
    todo = [d for d in dists if d not in _checked]
    if todo:
        check_pins(*todo)
        _checked.update(todo)


def install_agent_patches() -> None:
    """SPADE and slixmpp patches every agent process needs (once per process)."""
    if "agent" in _installed:
        return
    check_pins("spade", "slixmpp-multiplatform", "pyjabber")
    _checked.update(("spade", "slixmpp-multiplatform", "pyjabber"))
    import spade.agent
    from spade.behaviour import CyclicBehaviour

    CyclicBehaviour._step = _cancellable_step
    CyclicBehaviour.receive = _receive
    spade.agent.XMPPClient = rapp_xmpp_client_class()
    _keep_forms_off_messages()
    remove_upload_dir_at_exit()
    _installed.add("agent")


def spade_without_its_server() -> None:
    """Before SPADE's first import in a process that never runs an XMPP server (a Dynamic or Cloud
    Agent's runtime): spade/container.py (spade 4.1) imports `pyjabber.server` at module level for
    `run_container(embedded_xmpp_server=True)` alone, and with it sqlalchemy, alembic, aiohttp's web
    server and cryptography's x509 (0.4 s of a 0.65 s SPADE import, and their memory, in every RApp
    process; pyjabber also made an upload directory in each). `pyjabber` is stood in for by a module
    whose Server and Parameters refuse to be used. No effect where pyjabber is already imported."""
    import sys
    import types

    if "pyjabber" in sys.modules or "spade" in sys.modules:
        return
    try:
        _check_once("spade", "pyjabber")
    except PinMismatch:  # other versions: nothing stood in for; `rapp doctor` and the agent patches say why
        return

    class _NoServer:
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            raise RuntimeError("this process runs agents only: SPADE's embedded XMPP server is not loaded "
                               "(xmpp_server.compat.spade_without_its_server)")

    package = types.ModuleType("pyjabber", "stand-in: this process runs no XMPP server")
    package.__path__ = []  # a package: `import pyjabber.x` finds no other submodule
    for name in ("server", "server_parameters"):
        module = types.ModuleType(f"pyjabber.{name}", package.__doc__)
        module.Server = module.Parameters = _NoServer
        setattr(package, name, module)
        sys.modules[module.__name__] = module
    package.Server = package.Parameters = _NoServer
    sys.modules["pyjabber"] = package


def install_server_patches() -> None:
    """pyjabber patches of the embedded server (once per process)."""
    if "server" in _installed:
        return
    check_pins("pyjabber")
    import pyjabber.server as pjs

    pjs.setup_query_local_ip = lambda: None  # no extra listener on the auto-detected LAN address
    _patch_starttls_race()
    _patch_password_rounds()
    _patch_account_removal()
    _patch_session_routes()
    remove_upload_dir_at_exit()
    _installed.add("server")


def trace_logins_and_registrations(record) -> None:
    """`record(event, **fields)` for every failed SASL login (`login-failed`: the account tried, the
    peer) and every in-band registration (`registered`, or `registration-refused` for a name taken)
    the embedded server sees: told, not hidden (a RApp trying passwords or squatting names). Wraps
    pyjabber 0.4.5's (pinned) SASL.handle_auth and handle_iq without changing what they answer."""
    import base64

    from pyjabber.db.database import DB
    from pyjabber.db.model import Model
    from pyjabber.features.SASL.SASL import SASL
    from sqlalchemy import select

    if getattr(SASL, "_rapp_traced", False):
        SASL.record_structure = staticmethod(record)
        return
    handle_auth, handle_iq = SASL.handle_auth, SASL.handle_iq

    async def auth(self, element):
        stage = await handle_auth(self, element)
        if stage is None and element.attrib.get("mechanism") != "EXTERNAL":  # success returns the next stage
            try:
                account = base64.b64decode(element.text or "").split(b"\x00")[1].decode(errors="replace")
            except (ValueError, IndexError):
                account = ""
            SASL.record_structure("login-failed", account=account[:200], peer=_peer(self._peer))
        return stage

    async def iq(self, element):
        query = element.find("{jabber:iq:register}query")
        name = query.find("{jabber:iq:register}username") if query is not None else None
        if element.attrib.get("type") != "set" or name is None or not name.text:
            return await handle_iq(self, element)
        async with await DB.connection_async() as con:
            taken = (await con.execute(select(Model.Credentials.c.jid).where(Model.Credentials.c.jid == name.text))).fetchone()
        result = await handle_iq(self, element)
        SASL.record_structure("registration-refused" if taken else "registered", account=name.text[:200],
                          peer=_peer(self._peer))
        return result

    SASL.handle_auth, SASL.handle_iq, SASL._rapp_traced = auth, iq, True
    SASL.record_structure = staticmethod(record)  # named as the agents' own: tests/test_trace_records.py reads it


def _peer(peer) -> str:
    try:
        host, port = peer[:2]
        return f"{host}:{port}"
    except (TypeError, ValueError):
        return str(peer)


def configure_server(server, bind_host: str):
    """A pyjabber 0.4.5 Server (pinned) with its unauthenticated admin API (HTTP, port 9090) off and
    bound to `bind_host` instead of its domain name: both are private attributes."""
    server._http_server = None
    server._host = bind_host
    return server


# -- SPADE ------------------------------------------------------------------------------------
class ConnectsTo:
    """Mixed in before spade.agent.Agent: log in at `connect_addresses()[0]` (host, port) whatever
    the JID's domain is, and with more than one address, try the next when one is refused.

    SPADE 4.1.4's Agent._async_connect (pinned) calls `client.connect(host=jid.host, port=...)`: the
    JID's domain is a name, not where the server listens (loopback, a cluster node). The client's
    connect is replaced for that call; `reconnect_to(host, port)` calls the original (SPADE never
    reconnects by itself). slixmpp retries a refused address by itself; with fallback servers the
    next one is tried instead."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        _check_once("spade", "slixmpp-multiplatform")
        super().__init__(*args, **kwargs)

    def connect_addresses(self) -> list[tuple[str, int]]:
        raise NotImplementedError  # the host says where its server is

    def reconnect_to(self, host: str, port: int) -> None:
        self._connect_original(host=host, port=port)

    async def _async_connect(self) -> None:
        client = self.client
        connect = self._connect_original = client.connect
        addresses = self.connect_addresses()
        host, port = addresses[0]
        client.connect = lambda *a, **kw: connect(host=host, port=port)  # SPADE passes the JID's
        if len(addresses) == 1:
            await super()._async_connect()
            return
        # later: the failed attempt reschedules itself first, and connect() cancels that
        turn, connecting = itertools.count(1), [True]
        loop = asyncio.get_running_loop()

        def next_server(_error: object) -> None:
            h, p = addresses[next(turn) % len(addresses)]
            loop.call_later(0.2, lambda: connecting[0] and connect(host=h, port=p))
        client.add_event_handler("connection_failed", next_server)
        try:
            await super()._async_connect()
        finally:
            connecting[0] = False  # logged in, failed or given up: no further attempt
            client.del_event_handler("connection_failed", next_server)


class _RoutingContainer:
    """Stands in for SPADE's Container on one agent, so every send passes through the agent."""

    def __init__(self, real: Any, agent: Any) -> None:
        self._real, self._agent = real, agent

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)

    async def send(self, msg: Any, behaviour: Any = None) -> None:
        await self._agent.send(msg)


class AgentDoor(ConnectsTo):
    """Mixed in before spade.agent.Agent (`class RappAgent(AgentDoor, Agent)`): the agent's patches
    installed (pins checked first), and SPADE's private agent members replaced by public hooks:

    - `stanza_received(node)` gets every message stanza; it replaces Agent._message_received
      (Message.from_node, then dispatch to the behaviours' queues);
    - `send(msg)` gets every message a behaviour sends: SPADE's CyclicBehaviour.send goes to
      `agent.container.send`, which hands an agent of the same process the sender's own object
      without the agent seeing it; `container` becomes a stand-in whose send is the agent's.
      `local_agent(jid)` finds a running agent of this process, `leave_container()` forgets this
      one (SPADE's stop does not; a restarted agent of the same name would be handed messages);
    - the server address: see ConnectsTo."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        install_agent_patches()
        super().__init__(*args, **kwargs)
        self._spade_container = self.container  # set by Agent.__init__
        self.container = _RoutingContainer(self._spade_container, self)

    def stanza_received(self, node: Any) -> Any:
        return super()._message_received(node)

    def _message_received(self, node: Any) -> Any:
        return self.stanza_received(node)

    def local_agent(self, jid: str) -> Any:
        """The running agent of this process at `jid` (full, else bare), or None."""
        real = self._spade_container
        for key in (jid, jid.split("/", 1)[0]):
            if real.has_agent(key):
                agent = real.get_agent(key)
                if agent.is_alive():
                    return agent
        return None

    def leave_container(self) -> None:
        self._spade_container.unregister(str(self.jid))


# SPADE's Message.get_metadata, without its call (one per field and message read): its mapping is
# private in 4.1.4, an attribute getter reads it at C speed
metadata_of: Callable[[Any], dict[str, str]] = operator.attrgetter("_metadata")


async def _cancellable_step(self) -> None:
    """SPADE's CyclicBehaviour._step with one change: cancellation ends the behaviour.

    SPADE 4.1.4 catches CancelledError inside the loop and goes on, so a behaviour of an agent
    that was not stopped ignores cancellation forever (an event loop then never closes)."""
    while not self._done() and not self.is_killed():
        try:
            await self._run()
            await asyncio.sleep(0)
        except asyncio.CancelledError:
            self.kill()
            self.is_running = False
            raise
        except Exception as e:  # noqa: BLE001 - SPADE's own contract: an error kills the behaviour
            _log.exception("behaviour %s failed", self)
            self.kill(exit_code=e)
    try:
        await self.on_end()
    except Exception as e:  # noqa: BLE001
        _log.exception("on_end of %s failed", self)
        self.kill(exit_code=e)
    self.is_running = False
    self.agent.remove_behaviour(self)


async def _receive(self, timeout: float | None = None):
    """spade.behaviour.CyclicBehaviour.receive of spade 4.1.4 (pinned), same results: a queued
    message is returned at once, and a wait with a timeout runs in this task under
    asyncio.timeout. SPADE's asyncio.wait_for made a task per call even with a message waiting
    (bench/messages.py: a few microseconds of every message a behaviour receives)."""
    try:
        return self.queue.get_nowait()
    except asyncio.QueueEmpty:
        if not timeout:
            return None
    try:
        async with asyncio.timeout(timeout):
            return await self.queue.get()
    except TimeoutError:
        return None


_client_class = None


def rapp_xmpp_client_class():
    """SPADE's XMPP client with a shared TLS context when certificates are not verified, and
    message data forms left as XML.

    slixmpp builds a fresh default SSL context for every client and loads the system CA store into it
    twice (``create_default_context`` + ``set_default_verify_paths``): most of a login's event-loop
    time, spent on certificates that are never checked on loopback (docs/spade-pitfalls.md). With ``verify_security`` off every client shares one context without CA paths; with it on, nothing
    changes. The body repeats ``spade.xmpp_client.XMPPClient.__init__`` of spade 4.1.4 (pinned) with the
    context passed through; revisit on any SPADE upgrade (docs/spade-pitfalls.md).
    """
    global _client_class
    if _client_class is not None:
        return _client_class
    from slixmpp import ClientXMPP, __version__
    from spade.xmpp_client import XMPPClient

    from .tls import unverified_context

    class RappXMPPClient(XMPPClient):
        def __init__(self, jid, password, verify_security, auto_register):
            if verify_security:
                super().__init__(jid, password, verify_security, auto_register)
            else:
                self._init_unverified(jid, password, auto_register)
            drop_message_forms(self)

        def register_handler(self, handler, before=None):
            match_only_its_tag(handler)
            super().register_handler(handler, before)

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

    _client_class = RappXMPPClient
    return _client_class


# -- slixmpp ----------------------------------------------------------------------------------
async def end_filter_task(client: Any) -> None:
    """Cancel and await the client's stanza-filter task. slixmpp 1.12.0 (pinned) keeps it alive
    across disconnects in the private XMLStream._run_out_filters (for reconnecting), so a stopped
    client would leave it pending and asyncio would report "Task was destroyed but it is pending!"
    when the loop closes."""
    task = getattr(client, "_run_out_filters", None)
    if task is not None and not task.done():
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await task


def match_only_its_tag(handler) -> None:
    """A stanza handler whose matcher names its stanza's tag (MatchXPath `{ns}message/...`,
    StanzaPath `iq@type=set/...`) is tried only on stanzas with that tag.

    slixmpp's XMLStream.__spawn_event runs every handler's full matcher on every stanza (16 on an
    agent's client), where comparing the tag first costs a fraction of one (docs/spade-pitfalls.md).
    Replaces the instance's BaseHandler.match (slixmpp.xmlstream.handler.base, pinned 1.12.0); a matcher
    without a tag (an iq's id) is left as it is."""
    tag = _matcher_tag(getattr(handler, "_matcher", None))
    if tag is None or getattr(handler, "matches_only_its_tag", False):
        return
    full = tag.startswith("{")
    real = handler.match

    def match(stanza) -> bool:
        t = stanza.xml.tag
        return (t if full else t[t.rfind("}") + 1:]) == tag and real(stanza)

    handler.match, handler.unfiltered_match, handler.matches_only_its_tag = match, real, True


def _matcher_tag(matcher) -> str | None:
    from slixmpp.xmlstream.matcher import MatchIDSender, MatchXPath, StanzaPath

    if isinstance(matcher, MatchIDSender):  # only slixmpp.stanza.iq.Iq.send uses it: an iq's answer
        return "iq"
    criteria = getattr(matcher, "_criteria", None)
    if isinstance(matcher, MatchXPath) and isinstance(criteria, str) and criteria:
        if criteria.startswith("{"):  # a namespace may hold "/" (http://etherx.jabber.org/streams)
            ns_end = criteria.find("}")
            local = criteria[ns_end + 1:].split("/", 1)[0]
            return criteria[:ns_end + 1] + local if ns_end > 0 and local else None
        return criteria.split("/", 1)[0] or None
    if isinstance(matcher, StanzaPath) and criteria:
        first = criteria[0] if isinstance(criteria, (list, tuple)) else str(criteria).split("/", 1)[0]
        name = str(first).split("@", 1)[0]
        return name or None
    return None


def drop_message_forms(client) -> None:
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


# -- pyjabber (SPADE imports it in every agent process; the embedded server runs it) ----------
def remove_upload_dir_at_exit() -> None:
    """pyjabber 0.4.5 makes a temporary directory (`pyjabber_xep0363_*`, for HTTP uploads nobody
    uses here) when its upload module is imported, which SPADE does in every agent process, and
    never removes it. Removed when this process exits (empty or not: nothing of ours is in it)."""
    import atexit
    import shutil
    import sys

    import os
    from pathlib import Path

    module = sys.modules.get("pyjabber.plugins.xep_0363.upload_server")
    path = getattr(module, "TEMP_DIR", None)
    if path and not getattr(module, "_rapp_cleanup", False):
        atexit.register(shutil.rmtree, path, ignore_errors=True)
        module._rapp_cleanup = True
        for other in Path(path).parent.glob("pyjabber_xep0363_*"):  # of killed processes: unused, empty
            if str(other) != path:
                try:
                    os.rmdir(other)
                except OSError:
                    pass


_held: dict[int, list[bytes]] = {}


def _patch_starttls_race() -> None:
    """Hold client bytes that arrive while pyjabber upgrades a stream to TLS.

    pyjabber resets its XML stack only after `loop.start_tls` returns, but the client's new
    <stream:stream> can arrive (and be parsed into the old stack) before that: the login then
    hangs. Bytes received during the upgrade are replayed once the reset has happened.
    """
    from pyjabber.network.protocols.XMLProtocol import XMLProtocol
    from pyjabber.stream.negotiators.StreamNegotiator import StreamNegotiator

    if getattr(StreamNegotiator, "_rapp_patched", False):
        return
    original_received = XMLProtocol.data_received
    original_tls = StreamNegotiator._handle_tls

    def data_received(self, data):
        held = _held.get(id(self))
        if held is not None:
            held.append(data)
            return
        original_received(self, data)

    async def handle_tls(self, element):
        protocol = self._protocol
        _held[id(protocol)] = []
        try:
            return await original_tls(self, element)
        finally:
            held = _held.pop(id(protocol), [])
            if held:  # after the caller's stack reset, which runs before the loop turns again
                asyncio.get_running_loop().call_soon(
                    lambda: [original_received(protocol, d) for d in held])

    XMLProtocol.data_received = data_received
    StreamNegotiator._handle_tls = handle_tls
    StreamNegotiator._rapp_patched = True


PASSWORD_ROUNDS = 4096  # RFC 7677's minimum for SCRAM-SHA-256; pyjabber's own 100 000 cost ~35 ms


def _patch_password_rounds(rounds: int = PASSWORD_ROUNDS) -> None:
    """Store new accounts' password hashes with `rounds` PBKDF2 iterations.

    pyjabber hashes with 100 000 iterations at registration and again at every login (the stored
    count is used to verify): ~35 ms of server CPU each, most of an in-process Dynamic Agent's
    hand-off. This embedded server is a loopback development server whose accounts are the
    agents' own; verification still uses the count stored with each hash, so databases written
    with pyjabber's count keep working. Repeats pyjabber 0.4.5's `SASL._store_hash_task` (pinned)."""
    import bcrypt
    from pyjabber import AppConfig
    from pyjabber.db.database import DB
    from pyjabber.db.model import Model
    from pyjabber.features.SASL.SASL import SASL
    from sqlalchemy import insert

    if getattr(SASL, "_rapp_rounds", None) == rounds:
        return

    async def store_hash(self, password: str, jid_str: str):
        in_memory = AppConfig.app_config.database_in_memory
        hashed = await self._hash_scram_async(password=password, iterations=rounds,
                                              salt=bcrypt.gensalt(rounds=8) if in_memory else bcrypt.gensalt())
        async with await DB.connection_async() as con:
            async with con.begin():
                await con.execute(insert(Model.Credentials).values({"jid": jid_str, "hash_pwd": hashed}))

    SASL._store_hash_task = store_hash
    SASL._rapp_rounds = rounds


_offline: dict[str, list[bytes]] = {}  # the embedded server's offline messages, by recipient (bare or full JID)


def _patch_account_removal() -> None:
    """XEP-0077 account removal (`<query xmlns='jabber:iq:register'><remove/></query>` from a logged-in
    client), which pyjabber 0.4.5 lacks (its PluginManager answers feature-not-implemented): the
    account's credentials, roster rows and stored messages are deleted, the answer is sent, then
    every stream of the account is closed. Cores and the Platform delete the ephemeral accounts of
    RApp runs this way, as they do on Prosody and ejabberd."""
    from xml.etree import ElementTree as ET

    from pyjabber.db.database import DB
    from pyjabber.db.model import Model
    from pyjabber.network.ConnectionManager import ConnectionManager
    from pyjabber.plugins.PluginManager import PluginManager
    from pyjabber.stanzas.IQ import IQ
    from pyjabber.stanzas.error import StanzaError as SE
    from sqlalchemy import delete

    if getattr(PluginManager, "_rapp_removal", False):
        return

    class AccountRemoval:
        @staticmethod
        async def feed(jid, element):
            query = element.find("{jabber:iq:register}query")
            if element.attrib.get("type") != "set" or query is None or \
                    query.find("{jabber:iq:register}remove") is None:
                return SE.feature_not_implemented("query", "jabber:iq:register")
            async with await DB.connection_async() as con:
                async with con.begin():
                    await con.execute(delete(Model.Credentials).where(Model.Credentials.c.jid == jid.user))
                    await con.execute(delete(Model.Roster).where(Model.Roster.c.jid.in_([jid.user, jid.bare()])))
            for key in [k for k in _offline if k == jid.bare() or k.startswith(jid.bare() + "/")]:
                del _offline[key]  # nobody will read them: a deleted account's messages go with it
            clients = [c for c in ConnectionManager()._peerList.values()
                       if c.jid is not None and c.jid.bare() == jid.bare()]
            loop = asyncio.get_running_loop()
            for c in clients:  # after the answer below is written
                loop.call_later(0.05, c.transport.close)
            return ET.tostring(IQ(type_=IQ.TYPE.RESULT, id_=element.attrib.get("id"), to=str(jid)))

    original_init = PluginManager.__init__

    def init(self, jid) -> None:
        original_init(self, jid)
        self._plugins["jabber:iq:register"] = AccountRemoval()

    PluginManager.__init__ = init
    PluginManager._rapp_removal = True


def _patch_session_routes() -> None:
    """Route to live sessions only: an agent restarted under its own name is reachable at once.

    pyjabber 0.4.5 (pinned) keeps every resource it ever saw in its presence table: a stream that
    ends (clean `</stream>`, kill -9, timeout) is never removed from it, because the "lost
    connection" notice goes to a queue nobody reads, and a killed client's peer entry stays listed
    as online. A message to a bare JID goes to the resources of the highest `<priority/>`, compared
    as text, any presence type: SPADE's logout sends `unavailable` with priority 0, a new login's
    presence has none, so every later message to the bare JID went to the old, gone resource only,
    and was dropped.

    As a standard server does (RFC 6121 8.5.2, XEP-0160): when a client stream
    ends, its resource and peer entry are removed; a message to a bare JID goes to the available,
    connected resources of the highest non-negative priority (missing = 0, compared as numbers),
    else it is stored offline. Stored messages are delivered on the client's initial presence:
    pyjabber also flushed them at resource binding, before the client is online, into nothing.
    They are stored and delivered here, in the stanza handlers, in the order the server reads
    them: pyjabber's queue worker took a stored message and the recipient's "online" notice in no
    fixed order when both were waiting, and a message stored after the notice waited for a next
    one that never came (what that did: docs/spade-pitfalls.md). Stored messages go out oldest
    first (pyjabber: newest first).
    Resource conflicts cannot arise: pyjabber binds a fresh random resource for every session."""
    from pyjabber.features.presence.Enums import PresenceType
    from pyjabber.features.presence.PresenceFeature import Presence
    from pyjabber.network.ConnectionManager import ConnectionManager
    from pyjabber.network.protocols.XMLProtocol import XMLProtocol
    from pyjabber.queues.PendingMessage import PendingMessageWrapper
    from pyjabber.queues.QueueManager import QueueName, get_queue
    from pyjabber.stream.JID import JID
    from pyjabber.stream.handlers.StanzaHandler import StanzaHandler

    if getattr(Presence, "_rapp_routes", False):
        return

    def priority(entry) -> int:  # (resource, type, show, status, priority)
        try:
            return max(-128, min(127, int(entry[4])))
        except (TypeError, ValueError):
            return 0

    def most_priority(self, jid):
        live = [e for e in self.priority_by_jid(jid)
                if e[1] == PresenceType.AVAILABLE and priority(e) >= 0
                and self._connections.get_transport_online(JID(user=jid.user, domain=jid.domain, resource=e[0]))]
        top = max((priority(e) for e in live), default=None)
        return [e for e in live if priority(e) == top]

    def forget(jid) -> None:
        if jid is None or not jid.resource:
            return
        status = Presence()._online_status
        left = [e for e in status.get(jid.bare(), []) if e[0] != jid.resource]
        if left:
            status[jid.bare()] = left
        else:
            status.pop(jid.bare(), None)

    class StoreLocalAtOnce:
        """The stanza handler's message queue: a local recipient's message is stored at once,
        messages for other servers go to pyjabber's worker as before."""

        def __init__(self, queue):
            self.queue = queue

        async def put(self, item) -> None:
            if isinstance(item, PendingMessageWrapper) and not item.is_external:
                _offline.setdefault(str(item.jid), []).append(item.payload)
            else:
                await self.queue.put(item)

        def __getattr__(self, name):
            return getattr(self.queue, name)

    def deliver_stored(connections, jid) -> None:
        clients = connections.get_transport_online(jid)
        if not clients:
            return
        for key in (str(jid), jid.bare()):
            for payload in _offline.pop(key, []):
                for client in clients:
                    client.transport.write(payload)

    original_feed = Presence.feed

    async def feed(self, jid, element):
        try:
            return await original_feed(self, jid, element)
        finally:  # a presence parsed before its stream's end but handled after it
            if isinstance(jid, JID) and not any(c.jid == jid for c in self._connections._peerList.values()):
                forget(jid)
            elif isinstance(jid, JID) and "to" not in element.attrib and element.get("type") is None:
                deliver_stored(self._connections, jid)  # available now: what waited for it

    original_close = ConnectionManager.close

    def close(self, peer) -> None:
        client = self._peerList.get(peer)
        original_close(self, peer)
        forget(client.jid if client else None)

    original_lost = XMLProtocol.connection_lost

    def connection_lost(self, exc) -> None:
        if not self._server_incoming and not self._timeout_flag:
            client = self._connection_manager._peerList.pop(self._peer, None)
            forget(client.jid if client else None)
        original_lost(self, exc)

    original_handler_init = StanzaHandler.__init__

    def handler_init(self, transport) -> None:
        # pyjabber's __init__ ends by queueing a "new connection" for the bound JID, whose stored
        # messages the queue worker then writes to the client's online transports: none yet.
        # The initial presence queues the same notice once the client is online.
        queue = get_queue(QueueName.CONNECTIONS)
        queue.put_nowait = lambda item: None  # shadows asyncio.Queue's method for this call only
        try:
            original_handler_init(self, transport)
        finally:
            del queue.put_nowait
        self._message_queue = StoreLocalAtOnce(self._message_queue)

    Presence.most_priority = most_priority
    Presence.feed = feed
    ConnectionManager.close = close
    XMLProtocol.connection_lost = connection_lost
    StanzaHandler.__init__ = handler_init
    Presence._rapp_routes = True
