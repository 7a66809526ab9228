"""Per-agent XMPP passwords: each long-lived agent (Store, Platform, each Core) has its own.

A password is taken from, in order: the agent's constructor, `RAPP_XMPP_PASSWORD` (a deployer who
runs one agent per process may set it), or the agent's file `<credentials dir>/<account>.password`,
generated on first start. The directory is 0700 and each file 0600, owned by the user that runs the
agent; a file that others may read is refused, not used. No password is ever passed to a child
process: Dynamic and Cloud Agents get an ephemeral account of their own (agents/identity.py).

The credentials directory is `XmppSettings.credentials_dir`, `RAPP_CREDENTIALS_DIR`, or
`$XDG_DATA_HOME/rapp/credentials` (~/.local/share/rapp/credentials).
"""
from __future__ import annotations

import os
import re
import secrets
import stat
from pathlib import Path

_ACCOUNT = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")


class CredentialError(RuntimeError):
    pass


def generate_password() -> str:
    return secrets.token_urlsafe(24)


def default_credentials_dir() -> Path:
    given = os.environ.get("RAPP_CREDENTIALS_DIR")
    if given:
        return Path(given)
    data = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return data / "rapp" / "credentials"


def private_dir(path: str | os.PathLike) -> Path:
    """`path`, created 0700 if missing; an existing directory others can enter is tightened."""
    path = Path(path)
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    if stat.S_IMODE(path.stat().st_mode) & 0o077:
        os.chmod(path, 0o700)
    return path


class CredentialStore:
    def __init__(self, directory: str | os.PathLike | None = None):
        self.dir = Path(directory) if directory else default_credentials_dir()

    def path(self, account: str) -> Path:
        if not _ACCOUNT.match(account):
            raise CredentialError(f"not an account name: {account!r}")
        return self.dir / f"{account}.password"

    def password(self, account: str) -> str:
        """The account's password, generated and stored (0600) the first time."""
        path = self.path(account)
        private_dir(self.dir)
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            return self._read(path)
        with os.fdopen(fd, "w") as f:
            password = generate_password()
            f.write(password + "\n")
        return password

    def _read(self, path: Path) -> str:
        st = path.stat()
        if stat.S_IMODE(st.st_mode) & 0o077:
            raise CredentialError(f"{path} is readable by others (mode {stat.S_IMODE(st.st_mode):o}); "
                                  f"run: chmod 600 {path}")
        if st.st_uid != os.geteuid():
            raise CredentialError(f"{path} belongs to uid {st.st_uid}, not to this user ({os.geteuid()})")
        password = path.read_text().strip()
        if not password:
            raise CredentialError(f"{path} is empty: delete it to generate a new password")
        return password

    def forget(self, account: str) -> None:
        self.path(account).unlink(missing_ok=True)
