"""Recording benchmark (issue 45): what recording a run costs, and how long a replay takes.

The README's hazard run (NAO, seed 1; --house small for a quick look) three ways, one after the
other, each a `rapp run` / `rapp replay` process as a user runs it:

  off      --no-record: the floor (trace only)
  on       the default recording (message bodies, robot.jsonl, packages/, frames as blobs, run.mcap)
  replay   `rapp replay` of the recorded run: its RApp against the recorded answers, no simulation

Reported: wall time of each, recording overhead (on / off), bytes of the run folder per simulated
minute with and without the recording (and run.mcap's own size), and the replay's wall time as a
share of the recorded run's (issue 45's target: <= 10 %).

    python -m bench.recording [--house house|small] [--robot nao] [--seed 1] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ontology import robot_types

ROOT = Path(__file__).resolve().parent.parent
RAPP = [sys.executable, "-m", "cli.main"]


def folder_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def timed(cmd: list[str], log: Path) -> tuple[float, int]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAPP_")}
    t0 = time.monotonic()
    with open(log, "w") as out:
        code = subprocess.run(cmd, cwd=ROOT, env=env, stdout=out, stderr=subprocess.STDOUT,
                              stdin=subprocess.DEVNULL).returncode
    return time.monotonic() - t0, code


def hazard_run(args, out: Path, record: bool) -> dict:
    cmd = [*RAPP, "run", "hazard-detection", "--robot", args.robot, "--seed", str(args.seed), "--house", args.house,
           "--quiet", "--out", str(out)] + ([] if record else ["--no-record"])
    wall, code = timed(cmd, out.with_suffix(".log"))
    result = json.loads((out / "result.json").read_text()) if (out / "result.json").exists() else {}
    sim_min = max(result.get("duration_sim_s", 0.0), 1e-9) / 60
    mcap = out / "run.mcap"
    return {"wall_s": round(wall, 1), "exit": code, "all_correct": result.get("all_correct"),
            "sim_s": result.get("duration_sim_s"), "bytes": folder_bytes(out),
            "bytes_per_sim_min": round(folder_bytes(out) / sim_min),
            "mcap_bytes": mcap.stat().st_size if mcap.exists() else 0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.recording", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--house", default="house", choices=["house", "small"])
    ap.add_argument("--robot", default="nao", choices=robot_types.names())
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=None, help="directory for the runs (default: a temporary one)")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = ap.parse_args(argv)
    base = Path(args.out or tempfile.mkdtemp(prefix="bench-recording-"))
    base.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg()[0]
    off = hazard_run(args, base / "off", record=False)
    print(f"off     {off}", flush=True)
    on = hazard_run(args, base / "on", record=True)
    print(f"on      {on}", flush=True)
    replay_wall, replay_exit = timed([*RAPP, "replay", str(base / "on")], base / "replay.log")
    divergence = (base / "replay.log").read_text()[-400:]
    figures = {
        "house": args.house, "robot": args.robot, "seed": args.seed, "load_at_start": round(load, 2),
        "off": off, "on": on,
        "recording_overhead": round(on["wall_s"] / off["wall_s"], 3) if off["wall_s"] else None,
        "replay_wall_s": round(replay_wall, 1), "replay_exit": replay_exit,
        "replay_share_of_run": round(replay_wall / on["wall_s"], 3) if on["wall_s"] else None,
        "replay_said": divergence.strip().splitlines()[-1] if divergence.strip() else "",
        "load_at_end": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(figures, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))
    return 0 if off["exit"] == on["exit"] == replay_exit == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
