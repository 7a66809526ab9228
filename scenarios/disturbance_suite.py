"""`rapp run disturbances [--robot R] [--case NAME ...] [--json FILE]`: the hazard-detection RApp against
things that move (issue 18; papers 003/004): in the house `twodoors` (robots/houses/twodoors.yaml) the
robot walks from the living room to the bedroom's lamp, the short way through the north door, while

    person-crossing     a person paces to and fro across the living room, over the robot's way
    person-standing     a person stands still on the robot's way
    door-closed         someone closes the north door: the robot goes round through the south door
    box-in-doorway      a box is dropped in the north doorway: the same
    only-route-closed   both doors are closed: the way to the lamp is reported blocked (a hazard of its own)
    estop-resume        the owner says "stop" in the middle of a leg and "resume" 3 s later

One row per case and robot: finished, hazards correct (or, only-route-closed, the blocked route reported
with both doors), collisions (the robot's contacts with a person, from PyBullet; goal 0), the Core's reactive
strategies, the plans that failed and were made again (replans), durations. A case passes when the task
finishes as expected without touching anyone. docs/disturbances.md is this command's output.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Awaitable, Callable

from ontology import robot_types

from .hazard import run_hazard_detection
from .runner import RunInterrupted, add_recording_options, main_loop

HOUSE = "twodoors"
ROBOTS = robot_types.names()  # ontology/robot_types.py
FAST = ("door-closed",)  # the quickest whole case (tests/test_disturbance_suite.py, slow-marked)


async def stop_and_resume(handle, world, recorder, pause_s: float = 3.0) -> None:
    """The owner's "stop" once the robot is walking its third leg, "resume" `pause_s` (wall) seconds later."""
    while not (len(recorder.paths) >= 2 and recorder.moving_forward()):
        await world.sleep(0.2, drive=False)
    await world.sleep(1.0, drive=False)
    await handle.user.say(handle.core.address, "stop")
    await asyncio.sleep(pause_s)  # the owner's seconds: a stopped robot in an unpaced world makes no time pass
    await handle.user.say(handle.core.address, "resume")


def close(door: str, at: float = 3.0) -> dict:
    return {"kind": "door", "id": f"close-{door}", "door": door, "at": at, "angle": 0, "duration": 2.0}


@dataclass(frozen=True)
class Case:
    name: str
    disturbances: list = field(default_factory=list)
    blocked: tuple[str, ...] = ()  # doors the task must report closing the only way ("" : it must finish)
    during: Callable[..., Awaitable[None]] | None = None


CASES = {c.name: c for c in (
    Case("person-crossing", [{"kind": "person", "id": "walker", "speed": 0.6, "start": 2.0, "loop": True,
                              "route": [{"x": 2.3, "y": 3.7, "pause": 0.5}, {"x": 2.3, "y": 2.3, "pause": 0.5}]}]),
    Case("person-standing", [{"kind": "person", "id": "stander", "route": [[2.2, 3.1]]}]),
    Case("door-closed", [close("d_north")]),
    Case("box-in-doorway", [{"kind": "box", "id": "basket", "at": 3.0, "position": [3.5, 3.15],
                             "size": [0.35, 0.35, 0.7], "drop_height": 0.0}]),
    Case("only-route-closed", [close("d_north"), close("d_south")], blocked=("d_north", "d_south")),
    Case("estop-resume", during=stop_and_resume),
)}


def judge(case: Case, result: dict) -> dict:
    """One row of the table from a hazard run's result."""
    routes = result.get("routes_blocked", [])
    if case.blocked:  # the lamp is out of reach: its route reported blocked by exactly those doors
        reported = {b.removeprefix("door ") for r in routes for b in r.get("blocked_by", [])}
        correct = reported == set(case.blocked)
    else:
        correct = bool(result["all_correct"]) and not routes
    row = {"case": case.name, "robot": result["robot"], "finished": result["finished"],
           "hazards_correct": correct, "collisions": result["person_contacts"],
           "object_contacts": result["object_contacts"], "strategies": sorted(set(result["strategies"])),
           "replans": result["replans"], "obstacles_marked": result["obstacles_marked"],
           "estops": result["estops"], "duration_sim_s": result["duration_sim_s"],
           "duration_wall_s": result["duration_wall_s"], "trace": result["trace"]}
    row["passed"] = row["finished"] and correct and row["collisions"] == 0
    return row


async def run_case(case: Case, robot: str, seed: int = 1, out_dir: Path | None = None,
                   timeout_s: float = 900.0, record: bool = True, frames: bool = True) -> dict:
    out = Path(out_dir or tempfile.mkdtemp(prefix=f"disturbance-{case.name}-{robot}-"))
    result = await run_hazard_detection(robot, seed, HOUSE, out_dir=out, timeout_s=timeout_s,
                                        disturbances={"disturbances": case.disturbances} if case.disturbances
                                        else None, during=case.during, record=record, frames=frames)
    return judge(case, result)


def table(rows: list[dict]) -> str:
    head = ("| case | robot | finished | hazards correct | collisions | e-stops | strategies | replans | sim s | wall s |\n"
            "|---|---|---|---|---|---|---|---|---|---|")
    lines = [f"| {r['case']} | {r['robot']} | {'yes' if r['finished'] else 'NO'} | "
             f"{'yes' if r['hazards_correct'] else 'NO'} | {r['collisions']} | {r['estops']} | "
             f"{', '.join(r['strategies']) or '-'} | {r['replans']} | "
             f"{r['duration_sim_s']:.0f} | {r['duration_wall_s']:.0f} |" for r in rows]
    return "\n".join([head, *lines])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="rapp run disturbances", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robot", choices=ROBOTS, action="append", help="a robot (repeatable; default: both)")
    ap.add_argument("--case", choices=list(CASES), action="append", help="a case (repeatable; default: all)")
    ap.add_argument("--seed", type=int, default=1, help="draws the world (as in every scenario)")
    ap.add_argument("--json", dest="json_path", help="write the rows here (after every case)")
    ap.add_argument("--out", help="folder for each run's result, trace, plot and frames (default: temporary)")
    add_recording_options(ap, replay=False)
    a = ap.parse_args(argv)
    rows = []
    for name in a.case or list(CASES):
        for robot in a.robot or ROBOTS:
            out = Path(a.out) / f"{name}-{robot}" if a.out else None
            print(f"[disturbances] {name} on {robot} ...", flush=True)
            try:
                row = main_loop(run_case(CASES[name], robot, a.seed, out, record=not a.no_record,
                                         frames=not a.no_frames))
            except RunInterrupted as stop:  # the interrupted case is a row too (not passed), then the table
                if stop.result:
                    rows.append(judge(CASES[name], stop.result))
                if a.json_path:
                    Path(a.json_path).write_text(json.dumps(rows, indent=1))
                print(table(rows))
                print(f"[disturbances] {stop}", flush=True)
                return 128 + stop.signum
            rows.append(row)
            print(f"[disturbances] {name} on {robot}: {'passed' if row['passed'] else 'FAILED'} "
                  f"(finished {row['finished']}, correct {row['hazards_correct']}, collisions {row['collisions']}, "
                  f"strategies {row['strategies']}, replans {row['replans']}, {row['duration_wall_s']:.0f} s)",
                  flush=True)
            if a.json_path:  # after every case: a long run interrupted keeps what it measured
                Path(a.json_path).write_text(json.dumps(rows, indent=1))
    print(table(rows))
    for r in rows:  # each run's result.json, plot, frames, chat and trace
        print(f"  {r['case']} on {r['robot']}: {Path(r['trace']).parent}")
    if a.json_path:
        print(f"  rows: {a.json_path}")
    return 0 if all(r["passed"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
