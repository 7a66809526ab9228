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


def remove_upload_dir_at_exit() -> None:
    """pyjabber 0.4.5 makes a temporary directory (`pyjabber_xep0363_*`, for HTTP uploads nobody
    uses here) when its upload module is imported, which SPADE does in every agent process, and
    never removes it. Removed when this process exits (empty or not: nothing of ours is in it)."""
    import atexit
    import shutil
    import sys

    import os
    from pathlib import Path

    module = sys.modules.get("pyjabber.plugins.xep_0363.upload_server")
    path = getattr(module, "TEMP_DIR", None)
    if path and not getattr(module, "_rapp_cleanup", False):
        atexit.register(shutil.rmtree, path, ignore_errors=True)
        module._rapp_cleanup = True
        for other in Path(path).parent.glob("pyjabber_xep0363_*"):  # of killed processes: unused, empty
            if str(other) != path:
                try:
                    os.rmdir(other)
                except OSError:
                    pass
