"""What an agent process pays for its imports: SPADE as it comes against SPADE without its server.

Every Dynamic and Cloud Agent (and every warm worker) is a process that imports the project's agents,
and with them SPADE. spade/container.py imports pyjabber's server (sqlalchemy, alembic, aiohttp's web
server, cryptography's x509) for `run_container(embedded_xmpp_server=True)` alone; agents/runtime.py
stands in for it first (xmpp_server/compat.py `spade_without_its_server`). Each way, in fresh
processes taking turns: CPU time of the imports, and the process's memory after them (Pss and RSS,
/proc). The first way is the floor's peer: what the same imports cost as SPADE ships them.

    python -m bench.agent_imports [--runs 5] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

from .common import ROOT

PROBE = """
import resource, sys, time
t0 = time.process_time()
if sys.argv[1] == "without-server":
    from xmpp_server.compat import spade_without_its_server
    spade_without_its_server()
import agents.dynamic_agent, agents.cloud_agent
cpu = time.process_time() - t0
pss = next(int(l.split()[1]) for l in open("/proc/self/smaps_rollup") if l.startswith("Pss:"))
rss = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmRSS:"))
print(cpu, pss / 1024, rss / 1024)
"""
WAYS = ("as-shipped", "without-server")


def measure(way: str) -> tuple[float, float, float]:
    out = subprocess.run([sys.executable, "-c", PROBE, way], cwd=ROOT, capture_output=True, text=True,
                         check=True, timeout=300, stdin=subprocess.DEVNULL).stdout.split()
    cpu, pss, rss = (float(v) for v in out[-3:])
    return cpu, pss, rss


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.agent_imports", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0]
    runs: dict[str, list[tuple[float, float, float]]] = {w: [] for w in WAYS}
    measure(WAYS[0])  # a first import fills the page cache for both
    for _ in range(args.runs):
        for way in WAYS:
            runs[way].append(measure(way))
    figures = {"runs": args.runs, "load_at_start": round(load, 2), "load_at_end": round(os.getloadavg()[0], 2)}
    for way in WAYS:
        cpu, pss, rss = zip(*runs[way])
        figures[way] = {"import_cpu_s": round(statistics.median(cpu), 3), "pss_mb": round(statistics.median(pss), 1),
                        "rss_mb": round(statistics.median(rss), 1)}
    a, b = figures["as-shipped"], figures["without-server"]
    figures["cpu_ratio"] = round(b["import_cpu_s"] / a["import_cpu_s"], 3)
    figures["pss_saved_mb"] = round(a["pss_mb"] - b["pss_mb"], 1)
    print(json.dumps(figures, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(figures, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
