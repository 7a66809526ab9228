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
import json
import sys
import tempfile
from pathlib import Path

from agents.services.context import ServiceState
from robots import OdometryNoise, RobotAPI

from .hazard import COMMAND, RAPP_DIR, cm, finished, finite, score_owner
from .home_setup import HOUSES, home_description, home_map, scenario_world
from .plots import plot_hazard_run
from .recorder import RecordingAPI
from .runner import (Owner, Run, RunInterrupted, add_recording_options, check_interrupted, files_written, main_loop,
                     saving)

ROBOTS = ("nao", "elektron")  # the scenario's pair (paper 001's two robots), not every robot type

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


async def run_two_robots(seed: int = 1, house: str = "house", out_dir=None, json_path=None, shared: bool = False,
                         rtf: float = 0.0, settings=None, timeout_s: float = 1800.0, record: bool = True,
                         frames: bool = True) -> dict:
    """`record`: the run's recording and run.mcap (`frames`: with the cameras' frames; docs/recordings.md)."""
    out = Path(out_dir or tempfile.mkdtemp(prefix=f"two-robots-{seed}-"))
    out.mkdir(parents=True, exist_ok=True)
    world = scenario_world(house, seed, rtf=rtf)
    try:
        recorders = {kind: RecordingAPI(RobotAPI(world.add_robot(kind, odometry_noise=OdometryNoise.typical())),
                                        frames_dir=out / kind / "frames") for kind in ROBOTS}
        info, png, yaml_text = home_description(world, house, out)
        homes = {}
        for kind in ROBOTS:
            hazards = info.hazards if shared else [h for h in info.hazards if h.id in split(house, info.hazards)[kind]]
            homes[kind] = info.model_copy(update={"hazards": hazards})
        owners = [Owner(kind, recorders[kind], f"owner-{kind}-{seed}", COMMAND, home=(homes[kind], png, yaml_text))
                  for kind in ROBOTS]
        run = Run(out, world, RAPP_DIR, owners, settings=settings,
                  platform_kw={"services_state": ServiceState(work_dir=out / "services")},
                  grid=home_map(world, house), record=record, frames=frames)
        await run.run(timeout_s)
        with saving():
            result = {"seed": seed, "house": house, "shared": shared, "duration_sim_s": round(run.sim_s, 2),
                      "ok": all(run.ok(o) for o in owners), "reason": run.failure or "",
                      "trace": str(run.trace), "robots": {}, "truth": run.truth()}
            for owner in owners:
                kind, rec = owner.kind, owner.api
                rows, _ = score_owner(run, owner, homes[kind].hazards)
                r = {"robot": kind, "user": owner.user, "hazards": rows,
                     "all_correct": all(x["true_state"] == x["reported_state"] for x in rows),
                     "finished": finished(run, owner), "end": run.end_text(owner), "reason": run.reason(owner),
                     "localization_error_m": finite(rec.localization_error()),
                     "max_tracking_error_m": finite(rec.tracking_error()),
                     "duration_wall_s": round(owner.wall_s, 2), "plot": str(out / kind / "hazard_run.png")}
                plot_hazard_run(out / kind / "hazard_run.png", home_map(world, house), rec.paths, rec.localizations,
                                info.landmarks, rows, homes[kind].hazards,
                                title=f"{kind} (with another robot) seed {seed} ({house}): localization "
                                      f"{cm(r['localization_error_m'])}, tracking {cm(r['max_tracking_error_m'])}",
                                trajectory=[p[1:3] for p in run.trajectories[kind]])
                (out / kind / "chat.txt").write_text("\n".join(owner.transcript) + "\n")
                result["robots"][kind] = r
            result["all_correct"] = all(r["all_correct"] for r in result["robots"].values())
            Path(json_path or out / "result.json").write_text(json.dumps(result, indent=1))
            await run.finish_recording()
    finally:
        world.close()
    check_interrupted(result)
    return result


def summary(result: dict) -> str:
    lines = [f"two robots, one house ({result['house']}, seed {result['seed']}, "
             f"{'shared' if result['shared'] else 'split'} hazard lists): {result['duration_sim_s']:.0f} s sim"
             + (f"; {result['reason']}" if result["reason"] else "")]
    for kind, r in result["robots"].items():
        verdict = ("all correct" if r["all_correct"] else "MISCLASSIFIED") if r["finished"] else "DID NOT FINISH"
        lines.append(f"  {kind:9s} {verdict}, localization "
                     f"{cm(r['localization_error_m'])}, tracking {cm(r['max_tracking_error_m'])}, "
                     f"{r['duration_wall_s']:.0f} s wall")
        for h in r["hazards"]:
            lines.append(f"    {h['type']:4s} {h['id']:10s} true {h['true_state']:6s} reported {h['reported_state']}")
    out = Path(result["trace"]).parent
    lines.append(f"  wrote in {out}: {files_written(out)}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="rapp run two-robots", description=__doc__.split("\n\n")[0].replace("\n", " "))
    ap.add_argument("--seed", type=int, default=1, help="draws the world (as in every scenario)")
    ap.add_argument("--house", choices=HOUSES, default="house", help="the house (default: house, the full one)")
    ap.add_argument("--shared", action="store_true", help="both owners list every hazard")
    ap.add_argument("--json", dest="json_path", default=None, help="write the result JSON here (default: OUT/result.json)")
    ap.add_argument("--out", dest="out_dir", default=None, help="directory for plots, frames, chats and trace "
                                                                 "(default: a new temporary directory)")
    ap.add_argument("--rtf", type=float, default=0.0, help="real-time factor (0 = as fast as possible)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds to wait for the RApps' ends")
    add_recording_options(ap, replay=False)
    args = ap.parse_args(argv)
    try:
        result = main_loop(run_two_robots(args.seed, args.house, args.out_dir, args.json_path, args.shared, args.rtf,
                                          timeout_s=args.timeout, record=not args.no_record,
                                          frames=not args.no_frames))
    except RunInterrupted as stop:
        if stop.result:
            print(summary(stop.result))
        return 128 + stop.signum
    print(summary(result))
    return 0 if result["all_correct"] and result["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
