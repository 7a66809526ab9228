"""Floor of the hand-off benchmark: a bare Python process that imports SPADE and logs one agent
into the server (new account, in-band registration, like a Dynamic Agent), then prints the time.

    python -m bench.floor_login NAME      (server from RAPP_XMPP_* environment variables)

Prints `LOGGED_IN <time.time()>` once the agent's start() returned, then logs out and exits.
"""
from __future__ import annotations

import asyncio
import os
import sys
import time


async def _main(name: str) -> None:
    from spade.agent import Agent

    from xmpp_server.compat import ConnectsTo  # the address override alone: no agent patches

    host = os.environ.get("RAPP_XMPP_HOST", "127.0.0.1")
    port = int(os.environ.get("RAPP_XMPP_PORT", "5222"))
    domain = os.environ.get("RAPP_XMPP_DOMAIN", "localhost")
    password = os.environ.get("RAPP_XMPP_PASSWORD", "rapp-secret")

    class Bare(ConnectsTo, Agent):
        def connect_addresses(self) -> list[tuple[str, int]]:
            return [(host, port)]

    agent = Bare(f"{name}@{domain}", password, port=port, verify_security=False)
    await asyncio.wait_for(agent.start(auto_register=True), 30)
    print(f"LOGGED_IN {time.time():.6f}", flush=True)
    await agent.stop()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    asyncio.run(_main(argv[0] if argv else f"floor-{os.getpid()}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
