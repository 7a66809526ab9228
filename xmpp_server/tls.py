"""TLS contexts for XMPP clients."""
from __future__ import annotations

import ssl

_UNVERIFIED: ssl.SSLContext | None = None


def unverified_context() -> ssl.SSLContext:
    """One shared client context that checks no certificate (loopback, self-signed servers).

    slixmpp otherwise builds a default context per client and loads the system CA store into it
    twice: ~75 ms of the event loop per login, for certificates that are never checked."""
    global _UNVERIFIED
    if _UNVERIFIED is None:
        ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
        ctx.check_hostname = False
        ctx.verify_mode = ssl.CERT_NONE
        _UNVERIFIED = ctx
    return _UNVERIFIED
