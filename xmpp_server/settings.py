"""Where agents connect, decided in one place.

Fields come from keyword arguments first, then environment variables, then defaults, so the same
agents run against the embedded server, Prosody or ejabberd by configuration alone:

| field          | env var                 | default     |
|----------------|-------------------------|-------------|
| host           | RAPP_XMPP_HOST          | 127.0.0.1   | address the client connects to
| port           | RAPP_XMPP_PORT          | 5222        |
| fallback       | RAPP_XMPP_FALLBACK      | (none)      | other servers of the same domain (nodes of one
|                |                         |             | cluster), "host:port,host:port": tried in turn
|                |                         |             | after host:port when a connection is lost
| domain         | RAPP_XMPP_DOMAIN        | localhost   | JID domain (user@domain)
| password       | RAPP_XMPP_PASSWORD      | (none)      | this process's agent password, given by the
|                |                         |             | deployer; else its credentials file
| credentials_dir| RAPP_CREDENTIALS_DIR    | ~/.local/share/rapp/credentials | per-agent password files
| auto_register  | RAPP_XMPP_AUTO_REGISTER | true        | create accounts by in-band registration
| verify_tls     | RAPP_XMPP_VERIFY_TLS    | false       |
| force_xmpp     | RAPP_FORCE_XMPP         | false       | never use SPADE's in-process shortcut
| trace_file     | RAPP_TRACE_FILE         | (none)      | JSON Lines trace of every message
| start_timeout  | RAPP_START_TIMEOUT      | 20          | seconds an agent may take to log in
| web            | RAPP_AGENT_WEB          | false       | serve SPADE's agent web page (loopback)
"""
from __future__ import annotations

import os
from pathlib import Path

from pydantic import BaseModel, Field, field_validator

_ENV = {
    "host": "RAPP_XMPP_HOST",
    "port": "RAPP_XMPP_PORT",
    "fallback": "RAPP_XMPP_FALLBACK",
    "domain": "RAPP_XMPP_DOMAIN",
    "password": "RAPP_XMPP_PASSWORD",
    "credentials_dir": "RAPP_CREDENTIALS_DIR",
    "auto_register": "RAPP_XMPP_AUTO_REGISTER",
    "verify_tls": "RAPP_XMPP_VERIFY_TLS",
    "force_xmpp": "RAPP_FORCE_XMPP",
    "trace_file": "RAPP_TRACE_FILE",
    "start_timeout": "RAPP_START_TIMEOUT",
    "web": "RAPP_AGENT_WEB",
}


class XmppSettings(BaseModel):
    host: str = "127.0.0.1"
    port: int = Field(default=5222, ge=1, le=65535)
    fallback: list[str] = Field(default_factory=list)  # "host:port" of other nodes of the domain
    domain: str = "localhost"
    password: str | None = None
    credentials_dir: Path | None = None
    auto_register: bool = True
    verify_tls: bool = False
    force_xmpp: bool = False
    trace_file: Path | None = None
    start_timeout: float = Field(default=20.0, gt=0)
    web: bool = False

    @field_validator("fallback", mode="before")
    @classmethod
    def _parse_fallback(cls, v):
        items = [x.strip() for x in v.split(",") if x.strip()] if isinstance(v, str) else list(v or [])
        for item in items:
            host, _, port = str(item).rpartition(":")
            if not host or not port.isdigit() or not 1 <= int(port) <= 65535:
                raise ValueError(f"fallback server {item!r}: expected host:port")
        return items

    def addresses(self) -> list[tuple[str, int]]:
        """Where to connect, in order of preference: host:port, then the fallback servers."""
        rest = [(h, int(p)) for h, _, p in (a.rpartition(":") for a in self.fallback)]
        return [(self.host, self.port), *rest]

    @classmethod
    def from_env(cls, env: dict[str, str] | None = None, **overrides) -> "XmppSettings":
        env = os.environ if env is None else env
        values = {f: env[v] for f, v in _ENV.items() if env.get(v, "") != ""}
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls.model_validate(values)

    def jid(self, name: str) -> str:
        return name if "@" in name else f"{name}@{self.domain}"

    def password_for(self, account: str) -> str:
        """The password of `account` (a name or JID of this domain): the deployer's
        `password` when set, else the account's own credentials file (xmpp_server/credentials.py)."""
        from .credentials import CredentialStore

        if self.password:
            return self.password
        return CredentialStore(self.credentials_dir).password(account.split("@")[0])

    def to_env(self, fields=None) -> dict[str, str]:
        """Environment that makes a trusted child process (a CLI, a benchmark helper) connect the
        same way. Never a password: each process reads its own account's credentials file.
        `fields` narrows it to those settings (the sandbox of a RApp process gets no paths)."""
        out = {}
        for f, var in _ENV.items():
            v = getattr(self, f)
            if v is None or v == [] or f == "password" or (fields is not None and f not in fields):
                continue
            if isinstance(v, list):
                v = ",".join(v)
            out[var] = str(v).lower() if isinstance(v, bool) else str(v)
        return out
