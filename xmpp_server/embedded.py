"""Run pyjabber (SPADE's embedded XMPP server) bound to one host only, admin API off.

pyjabber binds its auto-detected LAN address next to the given host and serves an unauthenticated
admin API on port 9090 when the HTTP-upload plugin is on; both are switched off here. It also cannot
be restarted in one process (global queues bound to the first loop), so `rapp server` and the tests
run it in a process of its own (see process.py).
"""
from __future__ import annotations

import asyncio
import logging
import os
from pathlib import Path



def cert_dir(domain: str) -> Path:
    """A directory holding a self-signed certificate for `domain`, made once and cached."""
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "rapp" / "certs"
    base.mkdir(parents=True, exist_ok=True)
    if not (base / f"{domain}_cert.pem").exists():
        _write_self_signed(base, domain)
    return base


def _write_self_signed(base: Path, domain: str) -> None:
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, domain)])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder().subject_name(name).issuer_name(name)
        .public_key(key.public_key()).serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(days=1))
        .not_valid_after(now + datetime.timedelta(days=3650))
        .add_extension(x509.SubjectAlternativeName([x509.DNSName(domain)]), critical=False)
        .sign(key, hashes.SHA256())
    )
    tmp_key, tmp_cert = base / f".{domain}_key.{os.getpid()}", base / f".{domain}_cert.{os.getpid()}"
    tmp_key.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                          serialization.PrivateFormat.TraditionalOpenSSL,
                                          serialization.NoEncryption()))
    tmp_cert.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    os.replace(tmp_key, base / f"{domain}_key.pem")  # atomic: concurrent servers may race here
    os.replace(tmp_cert, base / f"{domain}_cert.pem")


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


CONNECTION_TIMEOUT_S = 600
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


def _patch_account_removal() -> None:
    """XEP-0077 account removal (`<query xmlns='jabber:iq:register'><remove/></query>` from a logged-in
    client), which pyjabber 0.4.5 lacks (its PluginManager answers feature-not-implemented): the
    account's credentials and roster rows are deleted, the answer is sent, then every stream of the
    account is closed. Cores and the Platform delete the ephemeral accounts of RApp runs this way,
    as they do on Prosody and ejabberd."""
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
    and was dropped (a Core restarted under its name never heard the Platform nor its owner).

    As a standard server does (RFC 6121 8.5.2, XEP-0160): when a client stream
    ends, its resource and peer entry are removed; a message to a bare JID goes to the available,
    connected resources of the highest non-negative priority (missing = 0, compared as numbers),
    else it is stored offline. Stored messages are delivered on the client's initial presence:
    pyjabber also flushed them at resource binding, before the client is online, into nothing.
    Resource conflicts cannot arise: pyjabber binds a fresh random resource for every session."""
    from pyjabber.features.presence.Enums import PresenceType
    from pyjabber.features.presence.PresenceFeature import Presence
    from pyjabber.network.ConnectionManager import ConnectionManager
    from pyjabber.network.protocols.XMLProtocol import XMLProtocol
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

    original_feed = Presence.feed

    async def feed(self, jid, element):
        try:
            return await original_feed(self, jid, element)
        finally:  # a presence parsed before its stream's end but handled after it
            if isinstance(jid, JID) and not any(c.jid == jid for c in self._connections._peerList.values()):
                forget(jid)

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

    Presence.most_priority = most_priority
    Presence.feed = feed
    ConnectionManager.close = close
    XMLProtocol.connection_lost = connection_lost
    StanzaHandler.__init__ = handler_init
    Presence._rapp_routes = True


def build_server(*, bind_host: str, port: int, s2s_port: int, domain: str,
                 db_path: str | None, verbose: bool = False, connection_timeout: int = CONNECTION_TIMEOUT_S):
    """A pyjabber Server for `domain` listening on bind_host:port only."""
    from loguru import logger as loguru_logger
    import pyjabber.server as pjs
    from pyjabber.server_parameters import Parameters

    loguru_logger.remove()
    if verbose:
        import sys
        loguru_logger.add(sys.stderr, level=os.environ.get("RAPP_XMPP_LOG_LEVEL", "INFO"))
    logging.getLogger("sqlalchemy").setLevel(logging.WARNING)

    pjs.setup_query_local_ip = lambda: None  # no extra LAN listener
    _patch_starttls_race()
    _patch_password_rounds()
    _patch_account_removal()
    _patch_session_routes()
    from .client_cleanup import remove_upload_dir_at_exit
    remove_upload_dir_at_exit()
    defaults = Parameters()
    params = Parameters(
        host=domain,
        client_port=port,
        server_port=s2s_port,
        database_path=db_path or ":memory:",
        database_in_memory=db_path is None,
        database_purge=False,
        cert_path=str(cert_dir(domain)),
        message_persistence=True,
        # pyjabber drops a client silent for 60 s (its default) and keeps the dropped connection
        # listed as online; a chat client without keep-alive pings reconnected every minute, and a
        # message to its bare JID in that gap was lost. SPADE agents ping every 55 s, too close
        # to 60 under load. Liveness of agents is the Core's heartbeat's job, not the server's.
        connection_timeout=connection_timeout,
        verbose=verbose,
        # pyjabber's stanza routing breaks when the upload plugin or item is removed, so both stay
        # and only its HTTP server (admin API + uploads on port 9090) is never started
        plugins=defaults.plugins,
        items=defaults.items,
    )
    server = pjs.Server(params)
    server._http_server = None  # unauthenticated admin API: off
    server._host = bind_host  # pyjabber binds its domain name; bind the configured address instead
    return server


async def serve(*, bind_host: str, port: int, s2s_port: int, domain: str, db_path: str | None,
                ready_callback=None, verbose: bool = False, connection_timeout: int = CONNECTION_TIMEOUT_S) -> None:
    """Run until cancelled or SIGINT/SIGTERM; call ready_callback once listening."""
    server = build_server(bind_host=bind_host, port=port, s2s_port=s2s_port, domain=domain,
                          db_path=db_path, verbose=verbose, connection_timeout=connection_timeout)
    task = asyncio.create_task(server.start())
    ready = asyncio.create_task(server.ready.wait())
    done, _ = await asyncio.wait({task, ready}, return_when=asyncio.FIRST_COMPLETED)
    if task in done:
        ready.cancel()
        raise RuntimeError(f"XMPP server failed to start on {bind_host}:{port}")
    # pyjabber's own SIGTERM handler raises SystemExit inside a callback, which the loop does not
    # turn into a shutdown: stop by cancelling its task instead
    import signal

    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, task.cancel)
    if ready_callback:
        ready_callback()
    try:
        await task
    except asyncio.CancelledError:
        pass
