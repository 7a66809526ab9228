"""A robot owner as a plain XMPP chat client (slixmpp, not SPADE): what any standard client does.

    user = ChatUser("alice", settings); await user.start()
    await user.say("core-nao1", "check the hazards")
    reply = await user.wait_for(lambda text: "finished" in text, timeout=60)
"""
from __future__ import annotations

import asyncio
import logging
import ssl
import time

from slixmpp import ClientXMPP
from .client_cleanup import close_client
from .probe import register_in_band
from .settings import XmppSettings


KEEPALIVE_S = 30


class ChatUser(ClientXMPP):
    def __init__(self, name: str, settings: XmppSettings, password: str | None = None,
                 keepalive_s: float = KEEPALIVE_S):
        super().__init__(settings.jid(name), password or settings.password_for(name))
        self.settings = settings
        self.enable_direct_tls = False
        if not settings.verify_tls:
            self.ssl_context.check_hostname = False
            self.ssl_context.verify_mode = ssl.CERT_NONE
        self.received: list[tuple[float, str, str]] = []  # (time, sender, text)
        self._new = asyncio.Event()
        self._session: asyncio.Future = asyncio.get_event_loop().create_future()
        self.register_plugin("xep_0077")
        self.register_plugin("xep_0199")
        self["xep_0199"].enable_keepalive(interval=keepalive_s)  # servers drop silent clients
        self.add_event_handler("register", self._register)
        self.add_event_handler("session_start", self._on_session)
        self.add_event_handler("failed_all_auth", lambda _: self._fail("authentication failed"))
        self.add_event_handler("message", self._on_message)
        self.add_event_handler("disconnected", self._on_disconnected)
        self.add_event_handler("connection_failed", self._on_connection_failed)
        self._stopping = False
        self._attempts = 0  # reconnection attempts so far: picks the address of the next one
        logging.getLogger("slixmpp").setLevel(logging.WARNING)

    async def _register(self, _event):  # slixmpp awaits only coroutine functions
        await register_in_band(self)

    def _on_session(self, _):
        self.send_presence()
        if not self._session.done():
            self._session.set_result(True)

    def _fail(self, why: str):
        if not self._session.done():
            self._session.set_exception(RuntimeError(why))

    def _on_message(self, msg):
        if msg["type"] in ("chat", "normal") and msg["body"]:
            self.received.append((time.time(), msg["from"].bare, msg["body"]))
            self._new.set()

    async def start(self, timeout: float = 20.0) -> None:
        self.connect(host=self.settings.host, port=self.settings.port)
        await asyncio.wait_for(self._session, timeout)

    def _on_disconnected(self, _):
        if not self._stopping:  # the server went away: try again until it is back
            self._retry()

    def _on_connection_failed(self, _):
        # slixmpp retries the same address by itself; with other servers, try the next one instead
        if not self._stopping and self.settings.fallback:
            self._retry()

    def _retry(self) -> None:
        addresses = self.settings.addresses()  # host:port, then the fallback servers, in turn
        host, port = addresses[self._attempts % len(addresses)]
        self._attempts += 1
        asyncio.get_event_loop().call_later(0.5, lambda: self._stopping or self.connect(host=host, port=port))

    async def stop(self) -> None:
        self._stopping = True
        await close_client(self, settle_s=0.05)

    async def say(self, to: str, text: str) -> None:
        self.send_message(mto=self.settings.jid(to), mbody=text, mtype="chat")

    def texts(self) -> list[str]:
        return [t for _, _, t in self.received]

    def transcript(self, start: int = 0, core: str | None = None) -> list[str]:
        """The chat as its owner got it, one line a message with its sender (the account's name); a
        sender other than `core` (the owner's robot) is marked so: a RApp that writes to the owner
        itself cannot pass for the Core. What the Core relays of a RApp comes labelled `[rapp]`."""
        core = str(core).split("/")[0] if core else None
        out = []
        for _, sender, text in self.received[start:]:
            who = str(sender).split("@")[0]
            if core and "@" in core and sender != core or core and "@" not in core and who != core:
                who += " (not your robot's Core)"
            out.append(f"{who}: {text}")
        return out

    async def wait_for(self, predicate, timeout: float = 30.0, start: int = 0) -> str:
        """The first message (from index `start` on) satisfying predicate(text)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        seen = start
        while True:
            for _, _, text in self.received[seen:]:
                if predicate(text):
                    return text
            seen = len(self.received)
            remaining = deadline - loop.time()
            if remaining <= 0:
                raise asyncio.TimeoutError(f"no matching message within {timeout}s; got {self.texts()}")
            self._new.clear()
            try:
                await asyncio.wait_for(self._new.wait(), remaining)
            except asyncio.TimeoutError:
                pass
