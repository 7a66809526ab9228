"""Waiting for agent processes takes no worker of the loop's default executor: with more running
children than it has workers, `to_thread` calls (the Platform's services) still run at once."""
from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time

from agents.process import exit_future


async def test_running_children_do_not_starve_to_thread():
    n = (min(32, (os.cpu_count() or 1) + 4)) + 2  # more than the default executor's workers
    children = [subprocess.Popen([sys.executable, "-c", "import time; time.sleep(3)"]) for _ in range(n)]
    exits = [exit_future(p) for p in children]
    try:
        t0 = time.monotonic()
        assert await asyncio.wait_for(asyncio.to_thread(lambda: 42), 2.0) == 42
        assert time.monotonic() - t0 < 1.0
        assert not any(f.done() for f in exits)
    finally:
        for p in children:
            p.kill()
    codes = await asyncio.wait_for(asyncio.gather(*exits), 10)
    assert codes == [-9] * n


async def test_exit_code_is_reported():
    p = subprocess.Popen([sys.executable, "-c", "raise SystemExit(7)"])
    assert await asyncio.wait_for(exit_future(p), 10) == 7
