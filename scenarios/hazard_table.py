"""Accuracy table of the hazard-detection experiment over seeds and robots (paper 001 sec. 4 goals:
localization <= 5 cm, tracking <= 10 cm, every hazard classified correctly).

    python -m scenarios.hazard_table --seeds 10 [--robots nao elektron] [--house house] [--out DIR]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import tempfile
from pathlib import Path

from .hazard import run_hazard_detection
from .home_setup import GENERATED, HOUSES

LOC_GOAL_M, TRACK_GOAL_M = 0.05, 0.10


def row_text(r: dict) -> str:
    def cm(v):
        return "   n/a" if v is None else f"{v * 100:6.1f}"
    wrong = [h["id"] for h in r["hazards"] if h["true_state"] != h["reported_state"]]
    return (f"{r['robot']:9s} {r['seed']:4d} {cm(r['localization_error_m'])} {cm(r['max_tracking_error_m'])}"
            f" {'yes' if r['all_correct'] else 'NO ':5s} {r['duration_sim_s']:8.0f} {r['duration_wall_s']:7.0f}"
            f"  {' '.join(wrong)}")


def summary_rows(results: list[dict]) -> list[str]:
    out = []
    for robot in sorted({r["robot"] for r in results}):
        rs = [r for r in results if r["robot"] == robot]
        for what, key in (("loc", "localization_error_m"), ("track", "max_tracking_error_m")):
            vals = [r[key] for r in rs if r[key] is not None]
            if vals:
                out.append(f"{robot:9s} {what:6s} max {max(vals) * 100:5.1f} cm  mean {statistics.mean(vals) * 100:5.1f} cm")
        correct = sum(r["all_correct"] for r in rs)
        loc_ok = sum(r["localization_error_m"] is not None and r["localization_error_m"] <= LOC_GOAL_M for r in rs)
        trk_ok = sum(r["max_tracking_error_m"] is not None and r["max_tracking_error_m"] <= TRACK_GOAL_M for r in rs)
        out.append(f"{robot:9s} all hazards correct in {correct}/{len(rs)} runs; localization <= 5 cm in "
                   f"{loc_ok}/{len(rs)}; tracking <= 10 cm in {trk_ok}/{len(rs)}")
    return out


def markdown(results: list[dict], title: str) -> str:
    """The table and its summary as Markdown (docs/hazard-table.md)."""
    lines = [f"# {title}", "",
             "| robot | seed | localization cm | tracking cm | all correct | sim s | wall s | wrong |",
             "|---|---|---|---|---|---|---|---|"]
    for r in results:
        wrong = " ".join(h["id"] for h in r["hazards"] if h["true_state"] != h["reported_state"])

        def cm(v):
            return "n/a" if v is None else f"{v * 100:.1f}"
        lines.append(f"| {r['robot']} | {r['seed']} | {cm(r['localization_error_m'])} | "
                     f"{cm(r['max_tracking_error_m'])} | {'yes' if r['all_correct'] else 'no'} | "
                     f"{r['duration_sim_s']:.0f} | {r['duration_wall_s']:.0f} | {wrong} |")
    lines += ["", "```", *summary_rows(results), "```", ""]
    return "\n".join(lines)


async def run_table(seeds: list[int], robots: list[str], house: str, out: Path) -> list[dict]:
    results = []
    print(f"{'robot':9s} {'seed':>4s} {'loc cm':>6s} {'trk cm':>6s} {'ok':5s} {'sim s':>8s} {'wall s':>7s}  wrong",
          flush=True)
    for robot in robots:
        for seed in seeds:
            try:
                r = await run_hazard_detection(robot, seed, house, out_dir=out / f"{robot}-{seed}")
            except Exception as e:  # noqa: BLE001 - one failed run must not end the table
                print(f"{robot:9s} {seed:4d} run failed: {type(e).__name__}: {e}", flush=True)
                continue
            results.append(r)
            print(row_text(r), flush=True)
    return results


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="hazard-table", description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="seeds 1..N")
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--robots", nargs="+", default=["nao", "elektron"], choices=["nao", "elektron"])
    ap.add_argument("--house", default="house", choices=HOUSES,
                    help="a hand-made house, or 'generated' (each seed its own generated house)")
    ap.add_argument("--houses", type=int, metavar="N", help="N generated houses (= --house generated --seeds N)")
    ap.add_argument("--out", default=None, help="directory for the runs' outputs and table.json")
    ap.add_argument("--markdown", metavar="FILE", help="also write the table as Markdown")
    ap.add_argument("--from-json", metavar="TABLE_JSON", help="no runs: rewrite the table of an earlier table.json")
    args = ap.parse_args(argv)
    if args.houses:
        args.house, args.seeds = GENERATED, args.houses
    if args.from_json:
        results = json.loads(Path(args.from_json).read_text())
    else:
        out = Path(args.out or tempfile.mkdtemp(prefix="hazard-table-"))
        seeds = list(range(args.first_seed, args.first_seed + args.seeds))
        results = asyncio.run(run_table(seeds, args.robots, args.house, out))
        (out / "table.json").write_text(json.dumps(results, indent=1))
        print(f"results: {out / 'table.json'}")
    print("\n".join(summary_rows(results)))
    if args.markdown:
        where = {"house": "the full 20 m x 20 m house", "small": "the small house"}.get(
            args.house, f"{args.seeds} generated houses (seeds {args.first_seed}..{args.first_seed + args.seeds - 1})")
        Path(args.markdown).write_text(markdown(results, f"Hazard detection on {where}"))
    return 0 if results and all(r["all_correct"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
