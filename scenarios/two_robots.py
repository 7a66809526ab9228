"""Two robots, one home, one RAPP system: a NAO and an Elektron in the same simulated house (one
World), each with its own owner (a ChatUser) and its own Core, Dynamic Agent and Cloud Agent, both
running the hazard-detection RApp at the same time on one Platform and one Store.

Each owner keeps his own home description on the Platform (same map and landmarks). By default the
owners split the hazards (each robot checks the ones of its part of the home: NAO the hall side,
Elektron the living-room side) so the two robots do not queue in the same doorways; --shared gives
both owners the full list (then both robots check every hazard and may block each other).

    python -m scenarios.two_robots --seed 1 --house house --json result.json
"""
from __future__ import annotations

import argparse
import asyncio
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from agents.services.context import ServiceState
from robots import OdometryNoise, RobotAPI, World

from agents.tracing import read_trace

from .hazard import (COMMAND, FINISHED, RAPP_DIR, cm, core_listening, finite, hazard_reports, reported,
                     rows_in_order, score_hazards, wait_until)
from .home_setup import HOUSES, hazard_overrides, home_description, home_map, upload_home
from .plots import plot_hazard_run
from .recorder import RecordingAPI
from .system import RappSystem

ROBOTS = ("nao", "elektron")
# which hazards each robot's owner lists (split mode), per house
SPLIT = {
    "house": {"nao": {"d_bedroom", "l_office"}, "elektron": {"d_kitchen", "l_living"}},
    "small": {"nao": {"l1"}, "elektron": {"d1"}},
}


def split(house: str, hazards) -> dict[str, set[str]]:
    """Which hazards each owner lists: SPLIT for the hand-made houses, else alternately."""
    if house in SPLIT:
        return SPLIT[house]
    return {kind: {h.id for h in hazards[i::len(ROBOTS)]} for i, kind in enumerate(ROBOTS)}


async def _run_one(handle, timeout_s: float) -> tuple[str, list[str], float]:
    """Ask this robot's Core to check the hazards; wait for the end; (last text, chat texts, wall s)."""
    t0 = time.monotonic()
    await handle.user.say(handle.core.address, COMMAND)
    end = await handle.user.wait_for(lambda t: t.startswith(FINISHED) or "did not understand" in t,
                                     timeout=timeout_s)
    return end, handle.user.transcript(core=handle.core.address), time.monotonic() - t0


async def run_two_robots(seed: int = 1, house: str = "house", out_dir=None, json_path=None, shared: bool = False,
                         rtf: float = 0.0, settings=None, timeout_s: float = 1800.0) -> dict:
    out = Path(out_dir or tempfile.mkdtemp(prefix=f"two-robots-{seed}-"))
    out.mkdir(parents=True, exist_ok=True)
    world = World.from_file(house, seed=seed, overrides=hazard_overrides(house, seed), rtf=rtf)
    try:
        recorders = {kind: RecordingAPI(RobotAPI(world.add_robot(kind, odometry_noise=OdometryNoise.typical())),
                                        frames_dir=out / kind / "frames") for kind in ROBOTS}
        info, png, yaml_text = home_description(world, house, out)
        state = ServiceState(work_dir=out / "services")
        homes = {}
        for kind in ROBOTS:
            hazards = info.hazards if shared else [h for h in info.hazards if h.id in split(house, info.hazards)[kind]]
            homes[kind] = info.model_copy(update={"hazards": hazards})
            upload_home(state, f"owner-{kind}-{seed}", homes[kind], png, yaml_text)
        trace = out / "trace.jsonl"
        trace.unlink(missing_ok=True)
        shutil.rmtree(out / "system", ignore_errors=True)
        async with RappSystem(out / "system", settings=settings, trace_file=trace,
                              platform_kw={"services_state": state}) as system:
            await system.publish(RAPP_DIR)
            handles = {kind: await system.add_robot(kind, api=recorders[kind], user=f"owner-{kind}-{seed}")
                       for kind in ROBOTS}
            for kind, h in handles.items():
                await wait_until(lambda h=h: core_listening(h.core), 30, f"Core of {kind} listening")
            sim0 = world.time
            runs = await asyncio.gather(*(_run_one(handles[k], timeout_s) for k in ROBOTS))
            sim_s = world.time - sim0
        truth = world.ground_truth()
        records = read_trace(trace, validate=True)
        result = {"seed": seed, "house": house, "shared": shared, "duration_sim_s": round(sim_s, 2),
                  "trace": str(trace), "robots": {}}
        for kind, (end, texts, wall_s) in zip(ROBOTS, runs):
            if "did not understand" in end:
                raise RuntimeError(f"the Core of {kind} did not start the RApp: {end}")
            rec = recorders[kind]
            reports = hazard_reports(records, handles[kind].core.address)  # this robot's Core only
            rows = score_hazards(homes[kind].hazards, truth, reported(reports))
            for row, frame in zip(rows_in_order(rows, [r.id for r in reports]), rec.frames):
                frame.rename(frame.with_name(f"{row['id']}.png"))
            r = {"robot": kind, "user": f"owner-{kind}-{seed}", "hazards": rows,
                 "all_correct": all(x["true_state"] == x["reported_state"] for x in rows),
                 "localization_error_m": finite(rec.localization_error()),
                 "max_tracking_error_m": finite(rec.tracking_error()),
                 "duration_wall_s": round(wall_s, 2), "plot": str(out / kind / "hazard_run.png")}
            plot_hazard_run(out / kind / "hazard_run.png", home_map(world, house), rec.paths, rec.localizations,
                            info.landmarks, rows, homes[kind].hazards,
                            title=f"{kind} (with another robot) seed {seed} ({house}): localization "
                                  f"{cm(r['localization_error_m'])}, tracking {cm(r['max_tracking_error_m'])}")
            (out / kind / "chat.txt").write_text("\n".join(texts) + "\n")
            result["robots"][kind] = r
        result["all_correct"] = all(r["all_correct"] for r in result["robots"].values())
    finally:
        world.close()
    Path(json_path or out / "result.json").write_text(json.dumps(result, indent=1))
    return result


def summary(result: dict) -> str:
    lines = [f"two robots, one house ({result['house']}, seed {result['seed']}, "
             f"{'shared' if result['shared'] else 'split'} hazard lists): {result['duration_sim_s']:.0f} s sim"]
    for kind, r in result["robots"].items():
        lines.append(f"  {kind:9s} {'all correct' if r['all_correct'] else 'MISCLASSIFIED'}, localization "
                     f"{cm(r['localization_error_m'])}, tracking {cm(r['max_tracking_error_m'])}, "
                     f"{r['duration_wall_s']:.0f} s wall")
        for h in r["hazards"]:
            lines.append(f"    {h['type']:4s} {h['id']:10s} true {h['true_state']:6s} reported {h['reported_state']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="two-robots", description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--house", choices=HOUSES, default="house")
    ap.add_argument("--shared", action="store_true", help="both owners list every hazard")
    ap.add_argument("--json", dest="json_path", default=None, help="write the result JSON here")
    ap.add_argument("--out", dest="out_dir", default=None, help="directory for plots, frames and trace")
    ap.add_argument("--rtf", type=float, default=0.0, help="real-time factor (0 = as fast as possible)")
    args = ap.parse_args(argv)
    result = asyncio.run(run_two_robots(args.seed, args.house, args.out_dir, args.json_path, args.shared, args.rtf))
    print(summary(result))
    print(f"result: {args.json_path or Path(result['trace']).parent / 'result.json'}")
    return 0 if result["all_correct"] else 1


if __name__ == "__main__":
    sys.exit(main())
