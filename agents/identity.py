"""Ephemeral XMPP identities for RApp runs (Dynamic and Cloud Agents).

Each run gets a fresh account with a random name and a one-time password, created by in-band
registration (XEP-0077) and deleted (XEP-0077 `<remove/>`) when the run ends in any way. The same
two calls work on the embedded server, Prosody and ejabberd. Accounts not yet deleted are kept
in a ledger (0600, in the creating agent's credentials directory), so the next start of a Core or
Platform that crashed deletes its leftovers (`sweep`).
"""
from __future__ import annotations

import asyncio
import json
import logging
import os
import secrets
from dataclasses import dataclass
from pathlib import Path

from xmpp_server.credentials import default_credentials_dir, generate_password, private_dir
from xmpp_server.probe import LoginError, probe_login, remove_account

log = logging.getLogger("rapp.identity")


RAPP_ACCOUNT_PREFIXES = ("dyn-", "cloud-")  # the accounts of RApp runs (Dynamic, Cloud Agents)


def is_rapp_account(jid: str) -> bool:
    """Whether an (authenticated) sender is a RApp run: its Core or Platform named its account."""
    return str(jid).split("@")[0].startswith(RAPP_ACCOUNT_PREFIXES)


def trace_refusal(agent, sender: str, action: str, refusal) -> None:
    """The `refused` record of an operation `agent` refused `sender` (told, not hidden)."""
    agent.record_structure("refused", action=action, sender=sender, reason=str(getattr(refusal, "reason", refusal))[:300],
                           code=getattr(refusal, "code", None), rapp_account=is_rapp_account(sender))


@dataclass(frozen=True)
class Identity:
    name: str  # the account's local part
    password: str

    def __repr__(self) -> str:  # never print the password
        return f"Identity({self.name!r})"


class EphemeralAccounts:
    def __init__(self, settings, owner: str, timeout: float = 10.0):
        """`owner`: the creating agent's account name (the ledger is named after it)."""
        self.settings, self.timeout = settings, timeout
        directory = Path(settings.credentials_dir) if settings.credentials_dir else default_credentials_dir()
        self.ledger = directory / f"{owner}.ephemeral.json"
        self._wanted: dict[str, int] = {}  # prefix -> how many accounts to keep made ahead
        self._made: dict[str, list[Identity]] = {}
        self._fillers: dict[str, asyncio.Task] = {}

    # -- ledger ---------------------------------------------------------------------------
    def _read(self) -> dict[str, str]:
        try:
            return json.loads(self.ledger.read_text())
        except (OSError, ValueError):
            return {}

    def _write(self, accounts: dict[str, str]) -> None:
        private_dir(self.ledger.parent)
        tmp = self.ledger.with_suffix(f".{os.getpid()}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            json.dump(accounts, f)
        os.replace(tmp, self.ledger)

    def pending(self) -> dict[str, str]:
        return self._read()

    # -- accounts -------------------------------------------------------------------------
    async def create(self, prefix: str) -> Identity:
        """A new account `<prefix>-<random>`, in the ledger before it exists on the server."""
        ident = Identity(f"{prefix}-{secrets.token_hex(5)}", generate_password())
        self._write({**self._read(), ident.name: ident.password})
        try:
            await self._on_a_server(probe_login, user=ident.name, password=ident.password, register=True)
        except LoginError:
            await asyncio.to_thread(self._forget, ident.name)
            raise
        return ident

    def reserve(self, prefix: str) -> Identity:
        """A new account `<prefix>-<random>` in the ledger only: its holder registers it at its first
        login (in-band, as `create` does) and the ledger's `delete`/`sweep` remove it either way. The
        Platform's Cloud Agents (warm workers and cold starts) and a Core's Dynamic Agents with no
        account made ahead (`take`): `create` costs the caller's loop a whole XMPP session (TLS,
        SCRAM, registration), which a fleet's burst of starts paid in its middle."""
        ident = Identity(f"{prefix}-{secrets.token_hex(5)}", generate_password())
        self._write({**self._read(), ident.name: ident.password})
        return ident

    def prepare(self, prefix: str, count: int = 1) -> None:
        """Keep `count` accounts for `prefix` made ahead, made one after another in the background
        while the robot is busy (a Core's next run of the same RApp then only logs in; made all at
        once they slowed the start that asked for them)."""
        self._wanted[prefix] = max(count, self._wanted.get(prefix, 0))
        filler = self._fillers.get(prefix)
        if filler is None or filler.done():
            self._fillers[prefix] = asyncio.create_task(self._fill(prefix))

    async def _fill(self, prefix: str) -> None:
        made = self._made.setdefault(prefix, [])
        while len(made) < self._wanted.get(prefix, 0):
            making = asyncio.create_task(self._make_one(prefix, made))
            try:
                await asyncio.shield(making)
            except LoginError as e:
                log.info("cannot make an account for %s ahead (%s); each run makes its own", prefix, e)
                return

    async def _make_one(self, prefix: str, made: list[Identity]) -> None:
        made.append(await self.create(prefix))

    def take(self, prefix: str) -> Identity:
        """An account made ahead for `prefix`, else one reserved (`reserve`): its holder must log
        in with in-band registration on (an account that exists answers "conflict" and the login
        goes on). Making one here cost a burst of first runs (a fleet's 20 robots told at once) a
        whole XMPP session each on their Cores' loops, on top of their agents' own logins."""
        made = self._made.get(prefix)
        return made.pop(0) if made else self.reserve(prefix)

    async def delete(self, name: str, password: str | None = None) -> bool:
        """Delete the account; True when gone (also when it no longer existed)."""
        password = password or self._read().get(name)
        if password is None:
            return True
        try:
            await self._on_a_server(remove_account, user=name, password=password)
        except LoginError as e:
            if "authentication failed" not in str(e):  # server away: keep it for the next sweep
                log.warning("could not delete account %s: %s", name, e)
                return False
        self._forget(name)
        return True

    async def _on_a_server(self, call, **kw):
        """`call(host, port, domain, ...)` at settings.host:port, else at the fallback servers (other
        nodes of a cluster) in turn; a refused login is not tried elsewhere."""
        s, last = self.settings, None
        for host, port in s.addresses():
            try:
                return await call(host, port, s.domain, timeout=self.timeout, **kw)
            except LoginError as e:
                if "authentication failed" in str(e):
                    raise
                last = e
        raise last

    def _forget(self, name: str) -> None:
        accounts = self._read()
        if accounts.pop(name, None) is not None:
            self._write(accounts)

    async def sweep(self, leftovers: dict[str, str] | None = None) -> list[str]:
        """Delete every account the ledger lists (leftovers of a crash; pass `pending()` taken at
        start so accounts of runs begun since are not touched). Returns their names."""
        gone = []
        for name, password in (self._read() if leftovers is None else leftovers).items():
            if await self.delete(name, password):
                gone.append(name)
        return gone

    async def close(self) -> None:
        """Delete the accounts made ahead and not taken."""
        self._wanted.clear()  # the fillers stop after the account in progress
        await asyncio.gather(*self._fillers.values(), return_exceptions=True)
        spare = [ident for made in self._made.values() for ident in made]
        self._fillers.clear()
        self._made.clear()
        await asyncio.gather(*(self.delete(i.name, i.password) for i in spare))
