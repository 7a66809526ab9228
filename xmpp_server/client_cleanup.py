"""Stopping a slixmpp client without leaving tasks behind."""
from __future__ import annotations

import asyncio
import contextlib

from slixmpp import ClientXMPP


async def end_filter_task(client: ClientXMPP | None) -> None:
    """Cancel and await the client's stanza-filter task. slixmpp keeps it alive across disconnects
    (for reconnecting), so a stopped client would leave it pending and asyncio would report
    "Task was destroyed but it is pending!" when the loop closes."""
    task = getattr(client, "_run_out_filters", None)
    if task is not None and not task.done():
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await task
