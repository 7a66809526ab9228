"""Stopping a slixmpp client without leaving tasks behind."""
from __future__ import annotations

import asyncio
import contextlib

from slixmpp import ClientXMPP


async def close_client(client: ClientXMPP, settle_s: float = 0.0) -> None:
    """Disconnect, give the stream end `settle_s` to go out, and leave no task behind."""
    client.disconnect()
    await asyncio.sleep(settle_s)
    await end_filter_task(client)


async def end_filter_task(client: ClientXMPP | None) -> None:
    """Cancel and await the client's stanza-filter task. slixmpp keeps it alive across disconnects
    (for reconnecting), so a stopped client would leave it pending and asyncio would report
    "Task was destroyed but it is pending!" when the loop closes."""
    task = getattr(client, "_run_out_filters", None)
    if task is not None and not task.done():
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await task
