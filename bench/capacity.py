"""The cost of one robot-task at growing fleet sizes, for the capacity model (docs/capacity.md).

    python -m bench.capacity [--sizes 1,1,1,5,10,20,50] [--json FILE] [--render-shared N]

Runs the fleet benchmark's rounds (bench/fleet.py: each robot runs the hazard-detection RApp in its
own small house, all at once, on one Platform, Store and XMPP server) at each size in turn, and
prints per round: CPU seconds per robot-task by process kind (bench/proc_cpu.py, /proc sampled every
0.5 s), the cores the round kept busy on average, messages and message bytes per task (from the
trace), the peak memory (Pss) per task, the Platform's service p95 and the round's wall time. The
machine's load (uptime) before and after each round is in the JSON. Run it alone, under the shared
CPU lock: the figures are the machine's.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import time
from pathlib import Path

from . import fleet
from .common import percentile

DEFAULT_SIZES = [1, 1, 1, 5, 10, 20, 50]
KIND_ORDER = ["cores", "render", "dynamic", "cloud", "platform", "store", "xmpp_server"]


def rows(rounds: list[dict]) -> list[dict]:
    """One summary row per round (what docs/capacity.md tabulates)."""
    out = []
    for r in rounds:
        per = r.get("per_task") or {}
        t = r["traffic"]
        out.append({"n": r["n"], "ok": r["ok"], "wall_s": round(r["wall_s"], 1),
                    "cpu_s_per_task": {k: per.get("cpu_s", {}).get(k, 0.0) for k in KIND_ORDER},
                    "cpu_s_per_task_total": per.get("cpu_s_total"), "sim_s_per_task": r.get("sim_s_per_task"),
                    "fds_peak": r.get("usage", {}).get("fds_peak"), "cores_busy": r.get("cpu_demand_cores"),
                    "messages_per_task": round(t["messages"] / r["n"]), "kb_per_task": round(t["bytes"] / r["n"] / 1024),
                    "pss_mb_per_task": per.get("pss_mb_total"), "pss_mb_peak": r.get("usage", {}).get("pss_mb_peak"),
                    "service_p95_ms": round(percentile(r["platform_ms"], 95), 1),
                    "services_p95_without_cloud_lifecycle_ms": round(percentile(r["services_ms"], 95), 1),
                    "p95_by_action": r["platform_p95_by_action"], "load_before": r["load_before"],
                    "load_after": r["load_after"], "heartbeats_late": r["heartbeats_late"],
                    "misclassified": r["misclassified"], "failed": r["failed"][:3]})
    return out


def markdown(table: list[dict]) -> str:
    head = ("| robots | ok | wall s | " + " | ".join(KIND_ORDER) + " | CPU-s / task | cores busy | msgs / task"
            " | kB / task | Pss MB / task | service p95 ms |")
    lines = [head, "|" + "---|" * (len(KIND_ORDER) + 10)]
    for r in table:
        cpu = " | ".join(f"{r['cpu_s_per_task'][k]:.2f}" for k in KIND_ORDER)
        lines.append(f"| {r['n']} | {'yes' if r['ok'] else 'NO'} | {r['wall_s']} | {cpu} | {r['cpu_s_per_task_total']}"
                     f" | {r['cores_busy']} | {r['messages_per_task']} | {r['kb_per_task']} | {r['pss_mb_per_task']}"
                     f" | {r['service_p95_ms']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.capacity", description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=",".join(map(str, DEFAULT_SIZES)), help="robots per round, in order")
    ap.add_argument("--json", metavar="FILE", help="write the rounds (all fields) and the summary as JSON")
    ap.add_argument("--render-shared", type=int, default=fleet.RENDER_SHARED, metavar="N",
                    help=f"render processes the worlds share (default {fleet.RENDER_SHARED}; 0: one per world, "
                         "as before 2026-11-28)")
    a = ap.parse_args(argv)
    if a.render_shared < 0:
        ap.error("--render-shared must be 0 or more")
    fleet.RENDER_SHARED = a.render_shared
    sizes = [int(x) for x in a.sizes.split(",")]
    started, load = time.strftime("%Y-%m-%d %H:%M:%S"), os.getloadavg()
    rounds = asyncio.run(fleet.run_rounds(sizes))
    if a.json:  # the raw rounds first: a fault in the summary loses nothing measured
        Path(a.json).write_text(json.dumps({"rounds": rounds}, default=str))
    table = rows(rounds)
    print(markdown(table))
    if a.json:
        Path(a.json).write_text(json.dumps({"started": started, "load_at_start": load, "render_shared": a.render_shared, "ended": time.strftime("%Y-%m-%d %H:%M:%S"),
                                            "nproc": os.cpu_count(), "kinds": fleet.KINDS, "summary": table,
                                            "rounds": rounds}, indent=1, default=str))
    return 0 if all(r["ok"] for r in rounds) else 1


if __name__ == "__main__":
    sys.exit(main())
