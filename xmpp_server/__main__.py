"""`python -m xmpp_server`: the embedded server as a process of its own (used by `rapp server`)."""
from __future__ import annotations

import argparse
import asyncio
import sys

from .embedded import CONNECTION_TIMEOUT_S, serve
from .ports import EXIT_PORT_IN_USE, bindable, free_port


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m xmpp_server")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=5222)
    p.add_argument("--s2s-port", type=int, default=0, help="server-to-server port (0: none chosen, a free one)")
    p.add_argument("--domain", default="localhost")
    p.add_argument("--db", default=None, help="SQLite file (default: in memory, see --memory)")
    p.add_argument("--connection-timeout", type=int, default=CONNECTION_TIMEOUT_S,
                   help="seconds a silent client stays connected (default %(default)s)")
    p.add_argument("--trace", default=None, help="append failed logins and in-band registrations to this trace file")
    p.add_argument("--verbose", action="store_true")
    a = p.parse_args(argv)
    if a.s2s_port == 0:
        a.s2s_port = free_port(a.host)

    listening = False

    def ready() -> None:
        nonlocal listening
        listening = True
        print(f"READY {a.host}:{a.port} domain={a.domain}", flush=True)

    for port in (a.port, a.s2s_port):
        if not bindable(a.host, port):
            print(f"error: port {port} on {a.host} is in use", file=sys.stderr, flush=True)
            return EXIT_PORT_IN_USE
    try:
        asyncio.run(serve(bind_host=a.host, port=a.port, s2s_port=a.s2s_port, domain=a.domain,
                          db_path=a.db, ready_callback=ready, verbose=a.verbose,
                          connection_timeout=a.connection_timeout, trace_file=a.trace))
    except (KeyboardInterrupt, SystemExit):
        if not listening:  # pyjabber exits so when it cannot listen, and on a signal before that
            print("error: the server stopped before it listened", file=sys.stderr, flush=True)
            return 1
    except RuntimeError as e:
        print(f"error: {e}", file=sys.stderr, flush=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
