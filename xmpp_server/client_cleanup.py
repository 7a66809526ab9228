"""Stopping a slixmpp client without leaving tasks behind."""
from __future__ import annotations

import asyncio

from slixmpp import ClientXMPP

from .compat import end_filter_task


async def close_client(client: ClientXMPP, settle_s: float = 0.0) -> None:
    """Disconnect, give the stream end `settle_s` to go out, and leave no task behind."""
    client.disconnect()
    await asyncio.sleep(settle_s)
    await end_filter_task(client)
