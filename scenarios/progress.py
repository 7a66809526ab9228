"""Live progress of a run, read from its trace file as it grows: the Core's state, the RApp's FSM
states, structure changes (spawn, hand-off, cloud agents, resume), every chat line, and the robot's
pose every few seconds. Plain lines (one per event), so they read the same on a terminal, in a log
or in CI; `--quiet` on the scenarios turns them off.

    follower = asyncio.create_task(follow(trace_path, pose=lambda: robot.pose))
    ...
    follower.cancel()
"""
from __future__ import annotations

import asyncio
import json
import sys
import time
from pathlib import Path

from ontology.trace import CHAT, Direction, RecordKind, StructureEvent, parse_record

_E = StructureEvent
SHOWN = {_E.SPAWN, _E.HANDOFF, _E.CLOUD_SPAWN, _E.CLOUD_DESTROY, _E.CLOUD_LOST, _E.ENDED, _E.DESTROY, _E.RESUME,
         _E.CATALOGUE_CHANGED}


def describe(rec: dict) -> str | None:
    """One line for a trace record worth showing, else None."""
    kind, agent = rec.get("kind"), str(rec.get("agent", "")).split("@")[0]
    if kind == RecordKind.STATE and rec.get("event") == "enter":
        who = "core" if rec.get("fsm") == "core" else f"rapp {rec.get('fsm')}"
        return f"{who}: {rec.get('state')}"
    if kind == RecordKind.STRUCTURE and rec.get("event") in SHOWN:
        detail = rec.get("dynamic") or rec.get("cloud") or rec.get("to") or rec.get("reason") or ""
        return f"{agent}: {rec['event']} {str(detail).split('@')[0]}".rstrip()
    if kind == RecordKind.MESSAGE and rec.get("performative") == CHAT and rec.get("dir") == Direction.SEND:
        return f"chat {agent} -> {str(rec.get('receiver', '')).split('@')[0]}: {rec.get('content', '')}"
    return None


async def follow(trace: str | Path, pose=None, out=None, pose_every: float = 5.0, period: float = 0.3) -> None:
    """Print progress lines until cancelled (then the lines written so far, once more);
    `pose()` -> (x, y, theta) or None."""
    out = out or sys.stdout
    path, t0, last_pose = Path(trace), time.monotonic(), 0.0
    offset = 0

    def read_new() -> None:
        nonlocal offset
        if not path.exists():
            return
        with path.open("rb") as f:
            f.seek(offset)
            data = f.read()
        complete = data.rfind(b"\n") + 1
        offset += complete
        for line in data[:complete].splitlines():
            try:
                rec = json.loads(line)
                parse_record(rec)  # a record of ontology.trace, else skipped like a broken line
            except ValueError:
                continue
            text = describe(rec)
            if text:
                print(f"[{time.monotonic() - t0:6.1f}s] {text}", file=out, flush=True)

    try:
        while True:
            read_new()
            now = time.monotonic()
            if pose is not None and now - last_pose >= pose_every:
                last_pose = now
                p = pose()
                if p is not None:
                    print(f"[{now - t0:6.1f}s] robot at x={p[0]:.2f} y={p[1]:.2f} theta={p[2]:.2f}",
                          file=out, flush=True)
            await asyncio.sleep(period)
    except asyncio.CancelledError:
        read_new()  # the run's last lines (destroy, resume) before it stops
