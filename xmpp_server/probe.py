"""A real XMPP login: register (in-band) if needed, authenticate, start a session, disconnect.

Used to wait until a server really accepts logins and by `rapp doctor`.
"""
from __future__ import annotations

import asyncio
import logging
import uuid

from slixmpp import ClientXMPP
from slixmpp.exceptions import IqError, IqTimeout

from .client_cleanup import close_client
from .tls import unverified_context


class LoginError(RuntimeError):
    pass


async def register_in_band(client: ClientXMPP) -> None:
    """XEP-0077 registration of the client's own account; an existing account is fine (the login
    that follows decides)."""
    iq = client.Iq()
    iq["type"] = "set"
    iq["register"]["username"] = client.boundjid.user
    iq["register"]["password"] = client.password
    try:
        await iq.send()
    except (IqError, IqTimeout):
        pass


class _ProbeClient(ClientXMPP):
    def __init__(self, jid: str, password: str, register: bool, then=None):
        super().__init__(jid, password, ssl_context=unverified_context())  # probes never verify certificates
        self.enable_direct_tls = False
        self.done: asyncio.Future = asyncio.get_running_loop().create_future()
        self.then = then  # coroutine function run with the client once the session started
        self.add_event_handler("session_start", self._on_session)
        self.add_event_handler("failed_all_auth", self._on_fail)
        self.add_event_handler("disconnected", self._on_disconnect)
        self.add_event_handler("connection_failed", self._on_refused)
        self.register_plugin("xep_0077")  # stanzas for registration and removal
        if register:
            self.add_event_handler("register", self._register)

    async def _register(self, _event):  # slixmpp awaits only coroutine functions
        await register_in_band(self)

    async def _on_session(self, _):
        try:
            if self.then is not None:
                await self.then(self)
        except Exception as e:  # noqa: BLE001 - reported to the caller, not lost in a handler
            if not self.done.done():
                self.done.set_exception(LoginError(f"{self.boundjid.bare}: {type(e).__name__}: {e}"))
        if not self.done.done():
            self.done.set_result(True)

    def _on_fail(self, _):
        if not self.done.done():
            self.done.set_exception(LoginError(f"authentication failed for {self.boundjid.bare}"))

    def _on_refused(self, err):
        if not self.done.done():
            self.done.set_exception(LoginError(f"cannot connect to {self.address}: {err}"))

    def _on_disconnect(self, _):
        if not self.done.done():
            self.done.set_exception(LoginError("disconnected before the session started"))


async def probe_login(host: str, port: int, domain: str, *, user: str | None = None,
                      password: str = "probe", register: bool = True, timeout: float = 5.0,
                      then=None) -> float:
    """Log in once (and run `then(client)` in the session); return the seconds it took. Raises
    LoginError on failure or timeout."""
    logging.getLogger("slixmpp").setLevel(logging.CRITICAL)
    user = user or f"probe-{uuid.uuid4().hex[:8]}"
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    client = _ProbeClient(f"{user}@{domain}", password, register, then)
    client.address = f"{host}:{port}"
    client.connect(host=host, port=port)
    try:
        await asyncio.wait_for(client.done, timeout)
    except asyncio.TimeoutError:
        raise LoginError(f"no XMPP session with {host}:{port} (domain {domain}) within {timeout:.1f}s") from None
    finally:
        await close_client(client)
    return loop.time() - t0


async def _remove_own_account(client: ClientXMPP) -> None:
    iq = client.Iq()
    iq["type"] = "set"
    iq["register"]["remove"] = True
    try:
        await iq.send(timeout=5)
    except IqError as e:
        raise LoginError(f"the server refused to remove {client.boundjid.bare}: "
                         f"{e.iq['error']['condition']}") from None


async def remove_account(host: str, port: int, domain: str, *, user: str, password: str,
                         timeout: float = 5.0) -> None:
    """Delete an account (XEP-0077 `<remove/>`, logged in as that account). LoginError when it
    cannot log in (already gone, wrong password) or the server refuses."""
    await probe_login(host, port, domain, user=user, password=password, register=False,
                      timeout=timeout, then=_remove_own_account)
