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

from .compat import configure_server, install_server_patches, trace_logins_and_registrations



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


CONNECTION_TIMEOUT_S = 600
def trace_writer(path: str | Path, domain: str):
    """`record(event, **fields)`: a structure record of the server's (agents/tracing.py's format; this
    floor is below the agents') appended to the run's trace with one write."""
    import json
    import time

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)

    def record(event: str, **fields) -> None:
        rec = {"t": round(time.time(), 6), "kind": "structure", "pid": os.getpid(), "agent": f"xmpp-server@{domain}",
               "event": event, **fields}
        os.write(fd, (json.dumps(rec, ensure_ascii=False) + "\n").encode())

    return record


def build_server(*, bind_host: str, port: int, s2s_port: int, domain: str,
                 db_path: str | None, verbose: bool = False, connection_timeout: int = CONNECTION_TIMEOUT_S,
                 trace_file: str | None = None):
    """A pyjabber Server for `domain` listening on bind_host:port only."""
    from loguru import logger as loguru_logger
    import pyjabber.server as pjs
    from pyjabber.server_parameters import Parameters

    loguru_logger.remove()
    if verbose:
        import sys
        loguru_logger.add(sys.stderr, level=os.environ.get("RAPP_XMPP_LOG_LEVEL", "INFO"))
    logging.getLogger("sqlalchemy").setLevel(logging.WARNING)

    install_server_patches()  # xmpp_server/compat.py: pyjabber's internals, version-checked
    if trace_file:  # failed logins and in-band registrations, in the run's trace
        trace_logins_and_registrations(trace_writer(trace_file, domain))
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
    return configure_server(pjs.Server(params), bind_host)


async def serve(*, bind_host: str, port: int, s2s_port: int, domain: str, db_path: str | None,
                ready_callback=None, verbose: bool = False, connection_timeout: int = CONNECTION_TIMEOUT_S,
                trace_file: str | None = None) -> None:
    """Run until cancelled or SIGINT/SIGTERM; call ready_callback once listening."""
    server = build_server(bind_host=bind_host, port=port, s2s_port=s2s_port, domain=domain,
                          db_path=db_path, verbose=verbose, connection_timeout=connection_timeout,
                          trace_file=trace_file)
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
