"""The paper's experiment (paper 001 sec. 4, paper 000 fig. 16): a robot owner asks by chat to check
the hazards; the Core downloads the hazard-detection RApp from the Store, its Dynamic Agent (and its
Cloud Agent) walk the robot to each door and lamp and report; the run is scored against ground truth.

    result = await run_hazard_detection("nao", seed=1, house="house", out_dir="out/")
    python -m scenarios.hazard --robot elektron --seed 3 --house small --json result.json
    python -m scenarios.hazard --robot nao --house generated --seed 5   # the house generated from seed 5
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

from agents.services.context import ServiceState
from agents.tracing import read_trace
from ontology import core as C
from ontology.trace import Direction, RecordKind, StructureEvent
from rapps.hazard_detection.hazard_detection.models import HazardReport
from robots import OdometryNoise, RobotAPI, World

from .home_setup import DOOR_OPEN_DEG, HOUSES, home_description, home_map, hazard_overrides, upload_home
from .plots import plot_hazard_run
from .recorder import RecordingAPI
from .progress import follow
from .system import RappSystem, wait_until

RAPP_DIR = Path(__file__).resolve().parent.parent / "rapps" / "hazard_detection"
COMMAND = "check the hazards"
FINISHED = ("hazard-detection finished", "hazard-detection ended")  # how the Core ends the task
REPORT_RE = re.compile(r"Hazard (\S+) \((door|lamp)\): (\w+)(?:, ([\d.]+) degrees)?")  # the chat text
CAPPED = re.compile(r"\.\.\.\[\+\d+ chars\]$")  # agents.tracing.cap's mark on a long content


def core_listening(core) -> bool:
    sup = core.supervisor
    return bool(core.vocabulary) and sup is not None and sup.behaviour.current == "s3_listen"


def hazard_reports(records: list[dict], core: str) -> list[HazardReport]:
    """What the RApp found at each hazard, in the order it reported: the data of its reports to
    the Core (`data["hazard"]`, a HazardReport), from the Core's side of the run's trace."""
    out = []
    for r in records:
        if (r["kind"] == RecordKind.MESSAGE and r["dir"] == Direction.RECV and r["agent"] == core
                and r["ontology"] == C.ONTOLOGY and r["action"] == C.Report.action_name
                and r["performative"] == "request"):
            if CAPPED.search(r["content"]):  # the long final summary; a hazard's report is short
                continue
            data = C.Report.model_validate_json(r["content"]).data
            if "hazard" in data:
                out.append(HazardReport.model_validate(data["hazard"]))
    return out


def reported(reports: list[HazardReport]) -> dict[str, dict]:
    """Per hazard, what the RApp reported: state and (doors) the estimated angle, to the tenth of a
    degree the user was told."""
    return {r.id: {"state": r.state, "angle": None if r.angle_deg is None else round(r.angle_deg, 1)}
            for r in reports}


def parse_reports(texts: list[str]) -> dict[str, dict]:
    """Per hazard, what the user was told in the chat: state and (doors) the estimated angle."""
    out = {}
    for text in texts:
        m = REPORT_RE.search(text)
        if m:
            out[m.group(1)] = {"state": m.group(3), "angle": float(m.group(4)) if m.group(4) else None}
    return out


def score_hazards(specs, truth, reports: dict) -> list[dict]:
    rows = []
    for spec in specs:
        rep = reports.get(spec.id, {})
        if spec.type == "door":
            angle = truth.doors[spec.id]
            row = {"id": spec.id, "type": "door", "true_state": "open" if angle > DOOR_OPEN_DEG else "closed",
                   "reported_state": rep.get("state"), "true_angle": angle, "estimated_angle": rep.get("angle")}
        else:
            row = {"id": spec.id, "type": "lamp", "true_state": "on" if truth.lamps[spec.id] else "off",
                   "reported_state": rep.get("state")}
        rows.append(row)
    return rows


async def run_hazard_detection(robot: str = "nao", seed: int = 1, house: str = "house", json_path=None,
                               out_dir=None, rtf: float = 0.0, settings=None, timeout_s: float = 1800.0,
                               progress: bool = False, disturbances=None, during=None) -> dict:
    """`disturbances`: people, doors and boxes of a scenario (robots/disturbances.py); `during`: an
    `async fn(handle, world, recorder)` run while the task runs (cancelled at its end), e.g. the
    owner's stop and resume. The result also counts the robot's contacts with people and objects and,
    from the trace, the Core's reactive strategies and the plan monitor's failed plans (replans)."""
    out = Path(out_dir or tempfile.mkdtemp(prefix=f"hazard-{robot}-{seed}-"))
    out.mkdir(parents=True, exist_ok=True)
    world = World.from_file(house, seed=seed, overrides=hazard_overrides(house, seed), rtf=rtf,
                            disturbances=disturbances)
    try:
        recorder = RecordingAPI(RobotAPI(world.add_robot(robot, odometry_noise=OdometryNoise.typical())),
                                frames_dir=out / "frames")
        user = f"owner-{robot}-{seed}"
        info, png, yaml_text = home_description(world, house, out)
        state = ServiceState(work_dir=out / "services")
        upload_home(state, user, info, png, yaml_text)
        trace = out / "trace.jsonl"
        trace.unlink(missing_ok=True)
        shutil.rmtree(out / "system", ignore_errors=True)  # a fresh Store and XMPP accounts
        async with RappSystem(out / "system", settings=settings, trace_file=trace,
                              platform_kw={"services_state": state}) as system:
            await system.publish(RAPP_DIR)
            if progress:  # live lines from the trace: Core and RApp states, chat, the robot's pose
                follower = asyncio.create_task(follow(trace, pose=lambda: recorder.robot.pose))
                system.on_stop(follower.cancel)
            handle = await system.add_robot(robot, api=recorder, user=user)
            await wait_until(lambda: core_listening(handle.core), 30, "Core listening", interval=0.05)
            sim0, wall0 = world.time, time.monotonic()
            await handle.user.say(handle.core.address, COMMAND)
            side = asyncio.create_task(during(handle, world, recorder)) if during is not None else None
            try:
                end = await handle.user.wait_for(lambda t: t.startswith(FINISHED)
                                                 or "did not understand" in t, timeout=timeout_s)
            finally:
                if side is not None:
                    side.cancel()
            if "did not understand" in end:
                raise RuntimeError(f"the Core did not start the RApp: {end}")
            sim_s, wall_s = world.time - sim0, time.monotonic() - wall0
            texts = handle.user.transcript(core=handle.core.address)  # each line with its sender
        records = read_trace(trace, validate=True)
        reports = hazard_reports(records, handle.core.address)
        rows = score_hazards(info.hazards, world.ground_truth(), reported(reports))
        for row, frame in zip(rows_in_order(rows, [r.id for r in reports]), recorder.frames):
            frame.rename(frame.with_name(f"{row['id']}{frame.suffix}"))  # .jpg from a noisy camera
        result = {
            "robot": robot, "seed": seed, "hazards": rows,
            "all_correct": all(r["true_state"] == r["reported_state"] for r in rows),
            "localization_error_m": finite(recorder.localization_error()),
            "max_tracking_error_m": finite(recorder.tracking_error()),
            "duration_sim_s": round(sim_s, 2), "duration_wall_s": round(wall_s, 2),
            "finished": end.startswith(FINISHED[0]), "end": end,
            "routes_blocked": [r.model_dump() for r in reports if r.type == "route"],
            "person_contacts": world.person_contacts(), "object_contacts": world.object_contacts(),
            **monitoring(records),
            "trace": str(trace), "plot": str(out / "hazard_run.png"),
        }
        plot_hazard_run(out / "hazard_run.png", home_map(world, house), recorder.paths, recorder.localizations,
                        info.landmarks, rows, info.hazards,
                        title=f"{robot} seed {seed} ({house}): localization {cm(result['localization_error_m'])},"
                              f" tracking {cm(result['max_tracking_error_m'])}")
        (out / "chat.txt").write_text("\n".join(texts) + "\n")
        (out / "recording.json").write_text(json.dumps({"localizations": recorder.localizations,
                                                        "paths": recorder.paths}))
    finally:
        world.close()
    Path(json_path or out / "result.json").write_text(json.dumps(result, indent=1))
    return result


def monitoring(records: list[dict]) -> dict:
    """From the trace: the reactive strategies the Core ran (in order), the plans that failed (the
    plan monitor's `plan-failed`: the task re-planned) and the obstacles it entered into the map."""
    events = [r for r in records if r["kind"] == RecordKind.STRUCTURE]
    return {"strategies": [r["strategy"] for r in events if r.get("event") == StructureEvent.STRATEGY
                           and r.get("phase") == "start"],
            "replans": sum(r.get("event") == StructureEvent.PLAN_FAILED for r in events),
            "obstacles_marked": sum(r.get("event") == StructureEvent.OBSTACLE_MARKED for r in events),
            "estops": sum(r.get("event") == StructureEvent.ESTOP for r in events)}


def finite(value: float, digits: int = 4) -> float | None:
    return round(value, digits) if math.isfinite(value) else None


def rows_in_order(rows: list[dict], ids: list[str]) -> list[dict]:
    """Rows in the order of `ids`: the order the hazards were checked (= order of the saved frames)."""
    by_id = {r["id"]: r for r in rows}
    return [by_id[i] for i in ids if i in by_id]


def rows_in_report_order(rows: list[dict], texts: list[str]) -> list[dict]:
    """Rows in the order the chat reported the hazards."""
    return rows_in_order(rows, [m.group(1) for m in map(REPORT_RE.search, texts) if m])


def cm(value: float | None) -> str:
    return "n/a" if value is None else f"{value * 100:.1f} cm"


def summary(result: dict) -> str:
    lines = [f"hazard detection: robot {result['robot']} seed {result['seed']}: "
             f"{'all correct' if result['all_correct'] else 'MISCLASSIFIED'}, "
             f"localization {cm(result['localization_error_m'])}, "
             f"tracking {cm(result['max_tracking_error_m'])}, "
             f"{result['duration_sim_s']:.0f} s sim / {result['duration_wall_s']:.0f} s wall"]
    for h in result["hazards"]:
        extra = (f" (true {h['true_angle']:.0f} deg, estimated {h['estimated_angle']})" if h["type"] == "door" else "")
        lines.append(f"  {h['type']:4s} {h['id']:10s} true {h['true_state']:6s} reported {h['reported_state']}{extra}")
    lines.append(f"  plot {result['plot']}\n  trace {result['trace']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="hazard-detection", description=__doc__.splitlines()[0])
    ap.add_argument("--robot", choices=["nao", "elektron"], default="nao")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--house", choices=HOUSES, default="house",
                    help="a hand-made house, or 'generated': the house generated from --seed")
    ap.add_argument("--json", dest="json_path", default=None, help="write the result JSON here")
    ap.add_argument("--out", dest="out_dir", default=None, help="directory for plot, frames and trace")
    ap.add_argument("--rtf", type=float, default=0.0, help="real-time factor (0 = as fast as possible)")
    ap.add_argument("--quiet", action="store_true", help="no progress lines while it runs, only the summary")
    args = ap.parse_args(argv)
    result = asyncio.run(run_hazard_detection(args.robot, args.seed, args.house, args.json_path, args.out_dir,
                                              args.rtf, progress=not args.quiet))
    print(summary(result))
    return 0 if result["all_correct"] else 1


if __name__ == "__main__":
    sys.exit(main())
