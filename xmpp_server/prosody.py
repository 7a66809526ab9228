"""A private Prosody instance as a child process (not the system service): own config, data,
certificate and log in a temporary directory, client port on loopback only, no s2s, no HTTP.

    async with ProsodyServer() as srv:     # or: with ProsodyServer() as srv / await srv.astart()
        settings = srv.settings()          # XmppSettings pointing at it

Accounts are created by in-band registration (XEP-0077, `allow_registration = true`); without it,
`srv.register("user", "password")` runs `prosodyctl --config FILE register` (see docs/prosody.md).
TLS: clients must use STARTTLS (`c2s_require_encryption = true`) with a self-signed certificate for
the domain, generated here with `cryptography`; settings() therefore has verify_tls=False.
"""
from __future__ import annotations

import asyncio
import datetime
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from .ports import free_port
from .probe import LoginError, probe_login
from .process import ExternalServer, ServerStartError, listening, terminate


def prosody_binary() -> str | None:
    """Path of the `prosody` executable, or None when Prosody is not installed."""
    return shutil.which("prosody")


def _lua(s: str | Path) -> str:
    return '"' + str(s).replace("\\", "\\\\").replace('"', '\\"') + '"'


def make_self_signed_cert(domain: str, cert_file: Path, key_file: Path, days: int = 30) -> None:
    """RSA key and a self-signed certificate for `domain` (and 127.0.0.1) in PEM files."""
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, domain)])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.SubjectAlternativeName(
                [x509.DNSName(domain), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .sign(key, hashes.SHA256()))
    key_file.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                           serialization.PrivateFormat.TraditionalOpenSSL,
                                           serialization.NoEncryption()))
    key_file.chmod(0o600)
    cert_file.write_bytes(cert.public_bytes(serialization.Encoding.PEM))


class ProsodyServer(ExternalServer):
    """Start and stop a private Prosody; same shape as EmbeddedServer."""

    def __init__(self, host: str = "127.0.0.1", port: int | None = None, domain: str = "localhost",
                 workdir: str | Path | None = None, allow_registration: bool = True,
                 verbose: bool = False, start_timeout: float = 20.0, binary: str | None = None):
        self.host = host
        self.port = port or free_port(host)
        self.domain = domain
        self.allow_registration = allow_registration
        self.verbose = verbose
        self.start_timeout = start_timeout
        self.binary = binary or prosody_binary()
        self._tmp = None if workdir else tempfile.TemporaryDirectory(prefix="rapp-prosody-")
        self.dir = Path(workdir or self._tmp.name)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.config_file = self.dir / "prosody.cfg.lua"
        self.log_file = self.dir / "prosody.log"
        self.proc: subprocess.Popen | None = None
        self._stderr = None

    # -- configuration ------------------------------------------------------------------------
    def config_text(self) -> str:
        d = self.dir
        return f"""-- private Prosody for RAPP (written by xmpp_server/prosody.py)
run_as_root = true          -- tests and CI run as root; never switch to the 'prosody' user
pidfile = {_lua(d / "prosody.pid")}
data_path = {_lua(d / "data")}
plugin_paths = {{}}
certificates = {_lua(d)}
log = {{ {"debug" if self.verbose else "info"} = {_lua(self.log_file)} }}

-- client connections on loopback only; no server-to-server, no components, no HTTP
c2s_ports = {{ {self.port} }}
c2s_interfaces = {{ {_lua(self.host)} }}
c2s_direct_tls_ports = {{}}
legacy_ssl_ports = {{}}
s2s_ports = {{}}
s2s_interfaces = {{}}
s2s_direct_tls_ports = {{}}
component_ports = {{}}
component_interfaces = {{}}
http_ports = {{}}
https_ports = {{}}
modules_disabled = {{ "s2s", "s2s_auth_certs", "offline" }}

modules_enabled = {{
    "roster"; "saslauth"; "tls"; "disco"; "ping"; "register"; "time"; "version"; "posix";
}}

authentication = "internal_hashed"
storage = "internal"

-- STARTTLS with a self-signed certificate; SASL PLAIN only after it
c2s_require_encryption = true
ssl = {{ certificate = {_lua(d / "localhost.crt")}; key = {_lua(d / "localhost.key")}; }}

-- in-band registration (XEP-0077) without throttling (no mod_limits either)
allow_registration = {"true" if self.allow_registration else "false"}
registration_throttle_max = 100000
registration_throttle_period = 1

VirtualHost {_lua(self.domain)}
"""

    def write_config(self) -> Path:
        (self.dir / "data").mkdir(exist_ok=True)
        cert, key = self.dir / "localhost.crt", self.dir / "localhost.key"
        if not cert.exists():
            make_self_signed_cert(self.domain, cert, key)
        self.config_file.write_text(self.config_text())
        return self.config_file

    def command(self) -> list[str]:
        return [self.binary or "prosody", "-F", "--config", str(self.config_file)]

    def prosodyctl(self, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        """Run `prosodyctl --config FILE ARGS...` for this instance (e.g. register u domain pw)."""
        ctl = shutil.which("prosodyctl") or "prosodyctl"
        return subprocess.run([ctl, "--config", str(self.config_file), *args], capture_output=True,
                              text=True, check=check, timeout=30)

    def register(self, user: str, password: str) -> None:
        """Create an account without in-band registration (works with the server running or not)."""
        self.prosodyctl("register", user, self.domain, password)

    # -- lifecycle ----------------------------------------------------------------------------
    def _spawn(self) -> None:
        if not self.binary:
            raise ServerStartError("prosody is not installed (apt-get install prosody)")
        self.write_config()
        env = dict(os.environ, PROSODY_CONFIG=str(self.config_file))
        self._stderr = open(self.dir / "prosody.stderr", "w")
        self.proc = subprocess.Popen(self.command(), stdin=subprocess.DEVNULL, stdout=self._stderr,
                                     stderr=subprocess.STDOUT, env=env, cwd=self.dir,
                                     start_new_session=True)

    async def astart(self) -> "ProsodyServer":
        await asyncio.to_thread(self._spawn)
        deadline = time.monotonic() + self.start_timeout
        last: Exception | None = None
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                why = self.diagnostics()
                self.stop()
                raise ServerStartError(f"prosody exited ({self.proc_rc}) at start: {why}")
            if not listening(self.host, self.port):
                await asyncio.sleep(0.05)
                continue
            if self.allow_registration:
                try:
                    await probe_login(self.host, self.port, self.domain,
                                      timeout=min(3.0, max(0.5, deadline - time.monotonic())))
                    return self
                except LoginError as e:
                    last = e
            else:
                return self
            await asyncio.sleep(0.1)
        why = self.diagnostics()
        self.stop()
        raise ServerStartError(f"prosody on {self.host}:{self.port} accepts no login within "
                               f"{self.start_timeout:.0f}s: {last}; {why}")

    def diagnostics(self, tail: int = 1500) -> str:
        out = []
        for f in (self.dir / "prosody.stderr", self.log_file):
            if f.exists():
                text = f.read_text(errors="replace").strip()
                if text:
                    out.append(f"{f.name}: ...{text[-tail:]}")
        return " | ".join(out) or "no output"

    proc_rc: int | None = None

    def stop(self, timeout: float = 10.0) -> None:
        if self.proc is None:
            return
        self.proc_rc = terminate(self.proc, timeout)
        if self._stderr:
            self._stderr.close()
            self._stderr = None
        self.proc = None


