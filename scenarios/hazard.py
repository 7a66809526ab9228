"""The paper's experiment (paper 001 sec. 4, paper 000 fig. 16): a robot owner asks by chat to check
the hazards; the Core downloads the hazard-detection RApp from the Store, its Dynamic Agent (and its
Cloud Agent) walk the robot to each door and lamp and report; the run is scored against ground truth.

    result = await run_hazard_detection("nao", seed=1, house="house", out_dir="out/")
    python -m scenarios.hazard --robot elektron --seed 3 --house small --json result.json
    python -m scenarios.hazard --robot nao --house generated --seed 5   # the house generated from seed 5
    rapp run hazard-detection --scheduled            # started by a schedule (sec. 7), not by a command

The RApp's findings come as data: each hazard's report carries a HazardReport (`data["hazard"]`), and
the Core tells the owner's client every report and the task's end as typed records
(ontology/results.py, scenarios/runner.py). Ctrl-C (or SIGTERM) writes result.json (`ok: false`),
the plot, chat and trace with what is known, and exits 128 + the signal.
"""
from __future__ import annotations

import argparse
import json
import math
import re
import sys
import tempfile
from dataclasses import asdict, fields, replace
from pathlib import Path

from agents.services.context import ServiceState
from agents.tracing import read_trace
from ontology import robot_types
from ontology.results import ReportRecord, TaskStage
from ontology.trace import RecordKind, StructureEvent
from rapps.hazard_detection.hazard_detection.models import HazardReport
from robots import OdometryNoise, RobotAPI
from robots.failure_modes import mechanical
from robots.lighting import Daylight
from robots.lived_in import LivedIn
from xmpp_server.link import LinkFaults, LinkStats

from .home_setup import DOOR_OPEN_DEG, HOUSES, home_description, home_map, scenario_world
from .plots import plot_hazard_run
from .recorder import RecordingAPI
from .runner import (Owner, Run, RunInterrupted, add_recording_options, check_interrupted, files_written, main_loop,
                     saving)

RAPP_DIR = Path(__file__).resolve().parent.parent / "rapps" / "hazard_detection"
COMMAND = "check the hazards"
SCHEDULE_LEAD_S = 120.0  # --scheduled: the robot's clock starts this long before the time written
ROBOTS = robot_types.names()  # ontology/robot_types.py


def hazard_reports(reports: list[ReportRecord]) -> list[HazardReport]:
    """What the RApp found at each hazard, in the order it reported: the data of its reports
    (`data["hazard"]`, a HazardReport); its other reports (the closing summary) carry none."""
    return [HazardReport.model_validate(r.data["hazard"]) for r in reports if "hazard" in r.data]


def reported(reports: list[HazardReport]) -> dict[str, dict]:
    """Per hazard, what the RApp reported: state and (doors) the estimated angle, to the tenth of a
    degree the user was told."""
    return {r.id: {"state": r.state, "angle": None if r.angle_deg is None else round(r.angle_deg, 1)}
            for r in reports}


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


def score_owner(run: Run, owner: Owner, specs) -> tuple[list[dict], list[HazardReport]]:
    """The owner's hazards scored against the world's truth (at the end), and the RApp's findings;
    the frames of the checks renamed after their hazards (<id>, <id>-lookN for a door looked at again)."""
    found = hazard_reports(owner.reports)
    rows = score_hazards(specs, run.world.ground_truth(), reported(found))
    frames = iter(owner.api.frames)  # one per look: a door looked at again has more (HazardReport.looks)
    for report in (r for r in found if r.type != "route" and r.state != "unknown"):
        shots = [f for f in (next(frames, None) for _ in range(report.looks)) if f is not None]
        for k, frame in enumerate(shots, 1):  # .jpg from a noisy camera
            frame.rename(frame.with_name(f"{report.id}{'' if k == len(shots) else f'-look{k}'}{frame.suffix}"))
    return rows, found


def finished(run: Run, owner: Owner) -> bool:
    rec = owner.record
    return rec is not None and rec.stage == TaskStage.RUN and rec.state == "Finished" and not run.signum


async def run_hazard_detection(robot: str = "nao", seed: int = 1, house: str = "house", json_path=None,
                               out_dir=None, rtf: float = 0.0, settings=None, timeout_s: float = 1800.0,
                               progress: bool = False, disturbances=None, during=None,
                               live: bool | None = None, record: bool = True, frames: bool = True,
                               scheduled: str | None = None, link: LinkFaults | None = None,
                               lived_in: LivedIn | None = None, daylight: Daylight | None = None,
                               mechanical_drive: bool = False, command_at: float | None = None,
                               rapp: Path | None = None) -> dict:
    """`disturbances`: people, doors and boxes of a scenario (robots/disturbances.py); `during`: an
    `async fn(handle, world, recorder)` run while the task runs (cancelled at its end), e.g. the
    owner's stop and resume; `progress`: show it (`live`: the rich panel, None = on a terminal). The
    result also counts the robot's contacts with people and objects and, from the trace's structure
    records, the Core's reactive strategies and the plan monitor's failed plans (replans). `record`:
    the run's recording and run.mcap (`frames`: with the camera's frames; docs/recordings.md).
    `scheduled` ("22:00"): the owner writes "check the hazards every day at 22:00" at the start
    instead of the command; the robot's simulated clock reads SCHEDULE_LEAD_S before it, and the
    Core starts the RApp when that time comes (agents/scheduler.py). `link`: the robot reaches the
    server over a flaky link (xmpp_server/link.py), named with what it did in the result's `link`.
    `lived_in`: the house changed since its map was made (robots/lived_in.py; the result's `lived_in`).
    `daylight`: the light of a time of day, windows and lamps of several strengths (robots/lighting.py;
    the result's `daylight`). `mechanical_drive`: the NAO's body moves by steps, the Elektron's by its
    wheel sides (robots/failure_modes.py mechanical; the result's `drive`). `command_at`: the simulated
    time the owner gives the command at (a re-simulation's: the recorded `command_sim_s`). `rapp`: the
    hazard RApp's source folder or a built package (default rapps/hazard_detection)."""
    out = Path(out_dir or tempfile.mkdtemp(prefix=f"hazard-{robot}-{seed}-"))
    out.mkdir(parents=True, exist_ok=True)
    # one robot: its large frames in two bands, one on each core (robots/render_process.py)
    world = scenario_world(house, seed, rtf=rtf, disturbances=disturbances, lived_in=lived_in, daylight=daylight,
                           render_bands=2)
    try:
        body = world.add_robot(robot, odometry_noise=OdometryNoise.typical())
        if mechanical_drive:
            await world.run(body.set_failure_modes, mechanical(body.failure_modes))
        recorder = RecordingAPI(RobotAPI(body), frames_dir=out / "frames")
        home = home_description(world, house, out)
        owner = Owner(robot, recorder, f"owner-{robot}-{seed}", COMMAND, home=home, link=link, command_at=command_at)
        if scheduled:
            owner.command, owner.deliver, owner.core_kw = schedule_owner(world, scheduled)
        run = Run(out, world, rapp or RAPP_DIR, [owner], settings=settings,
                  platform_kw={"services_state": ServiceState(work_dir=out / "services")},
                  record=record, frames=frames, grid=home_map(world, house))
        side = None if during is None else (lambda run: during(owner.handle, world, recorder))
        await run.run(timeout_s, during=side,
                      show=dict(pose=lambda: recorder.robot.pose, live=live) if progress else None)
        with saving():
            info = home[0]
            rows, found = score_owner(run, owner, info.hazards)
            result = {
                "robot": robot, "seed": seed, "house": house, "hazards": rows,
                "all_correct": all(r["true_state"] == r["reported_state"] for r in rows),
                "localization_error_m": finite(recorder.localization_error()),
                "max_tracking_error_m": finite(recorder.tracking_error()),
                "frames": frame_counts(owner.reports, recorder.captures),
                "duration_sim_s": round(run.sim_s, 2), "duration_wall_s": round(run.wall_s, 2),
                "finished": finished(run, owner), "end": run.end_text(owner),
                "trigger": owner.record.trigger.value if owner.record is not None else None,
                "ok": run.ok(owner), "reason": run.reason(owner),
                "routes_blocked": [r.model_dump() for r in found if r.type == "route"],
                "person_contacts": world.person_contacts(), "object_contacts": world.object_contacts(),
                **monitoring(read_trace(run.trace, validate=True)),
                "trace": str(run.trace), "plot": str(out / "hazard_run.png"),
                "link": link_result(run, owner, link), "lived_in": world.lived_in, "daylight": world.daylight,
                "drive": "mechanical" if mechanical_drive else "statistical",
                "scheduled": scheduled, "rtf": rtf, "command_sim_s": owner.given_at,
                "disturbances": None if disturbances is None else _jsonable(disturbances),
                "during": None if during is None else getattr(during, "__name__", repr(during)),
            }
            plot_hazard_run(out / "hazard_run.png", home_map(world, house), recorder.paths, recorder.localizations,
                            info.landmarks, rows, info.hazards,
                            title=f"{robot} seed {seed} ({house}): localization {cm(result['localization_error_m'])},"
                                  f" tracking {cm(result['max_tracking_error_m'])}"
                                  + (f" ({run.interrupted})" if run.signum else ""),
                            trajectory=[p[1:3] for p in run.trajectories[robot]], unmapped=unmapped(world))
            (out / "chat.txt").write_text("\n".join(owner.transcript) + "\n")
            (out / "recording.json").write_text(json.dumps({"localizations": recorder.localizations,
                                                            "paths": recorder.paths}))
            Path(json_path or out / "result.json").write_text(json.dumps(result, indent=1))
            await run.finish_recording()
    finally:
        world.close()
    check_interrupted(result)
    return result


def unmapped(world) -> list:
    """What stands in the world but not on the map: furniture moved or left since it was made, the
    passage doors' leaves where they are now."""
    mapped = {(b.name, b.x, b.y, b.yaw) for b in world.mapped_plan.furniture}
    moved = [b for b in world.plan.furniture if (b.name, b.x, b.y, b.yaw) not in mapped]
    doors = {d.id: d.angle for d in world.mapped_plan.doors}
    changes = world.lived_in or {}
    return moved + [d.leaf_box() for d in world.plan.doors if any(c["id"] == d.id for c in changes.get("doors", []))
                    and doors.get(d.id) != d.angle]


REALISM = ("none", "full")  # full: every realism knob this build has (docs/realism.md)
FULL_LINK = "delay=40ms,jitter=20ms,loss=1%,outage=5s@60s,drop"  # a home Wi-Fi that drops once


def realism(level: str, seed: int, lived_in: bool = False, link: LinkFaults | None = None,
            daylight: str | None = None, mechanical_drive: bool = False) -> dict:
    """run_hazard_detection's realism keywords for `--realism LEVEL` plus the single knobs given
    (`daylight`: "random" or a time of day, as --daylight takes it)."""
    full = level == "full"
    link = link or (LinkFaults.parse(FULL_LINK) if full else None)
    daylight = daylight or ("random" if full else None)
    return {"lived_in": LivedIn(seed=seed) if lived_in or full else None,
            "link": link and replace(link, seed=seed),
            "daylight": None if daylight is None else Daylight(seed=seed, hour=time_of_day(daylight)),
            "mechanical_drive": mechanical_drive or full}


_CLOCK = re.compile(r"(\d{1,2}):(\d{2})")
_HOURS = re.compile(r"\d{1,2}(?:\.\d+)?")


def time_of_day(text: str) -> float | None:
    """--daylight's value: "random" (None: drawn from the seed), "HH:MM" (00:00-23:59) or hours ("18.5")."""
    if text == "random":
        return None
    clock = _CLOCK.fullmatch(text)
    if clock and int(clock[1]) < 24 and int(clock[2]) < 60:
        return int(clock[1]) + int(clock[2]) / 60.0
    if _HOURS.fullmatch(text) and float(text) < 24.0:
        return float(text)
    raise argparse.ArgumentTypeError(f"--daylight: {text!r} is not 'random', HH:MM (00:00-23:59) or hours 0-24")


def daylight_arg(text: str) -> str:
    time_of_day(text)  # checked here, drawn per run
    return text


def _jsonable(value):
    return value if isinstance(value, (dict, list)) else str(value)


# what a re-simulation takes from a recorded result.json (--replay), and what the run found: every key a
# result has is one or the other, so a recording with a key this build does not know is refused, not
# re-simulated in another world (tests/test_hazard_resim.py holds the run's keys to these two sets)
REPLAYED = frozenset({"robot", "seed", "house", "rtf", "lived_in", "link", "daylight", "drive", "trigger",
                      "scheduled", "command_sim_s", "disturbances", "during"})
OUTCOMES = frozenset({"hazards", "all_correct", "localization_error_m", "max_tracking_error_m", "frames",
                      "duration_sim_s", "duration_wall_s", "finished", "end", "ok", "reason",
                      "routes_blocked", "person_contacts", "object_contacts", "strategies", "replans",
                      "obstacles_marked", "estops", "trace", "plot"})


def recorded_settings(rec: dict) -> dict:
    """run_hazard_detection's keywords that re-run a recorded run (`rapp run hazard-detection --replay`):
    its robot, seed, house, real-time factor, every realism knob (lived-in, link, daylight, drive), its
    disturbances, schedule and the simulated time of its command. ResimError (scenarios/resim.py) for a
    recording with something this build cannot apply: re-simulating it would run another world."""
    from .resim import ResimError

    unknown = sorted(set(rec) - REPLAYED - OUTCOMES)
    if unknown:
        raise ResimError(f"the recording's result.json has {', '.join(unknown)}, which this build does not know: "
                         "it cannot re-simulate that run")
    if rec.get("during"):
        raise ResimError(f"the recorded run had {rec['during']!r} acting during it (a disturbance-suite case), "
                         "which result.json cannot give again: re-run that case with `rapp run disturbances`")
    if rec.get("trigger") == "scheduled" and not rec.get("scheduled"):
        raise ResimError("the recorded run was started by a schedule whose time it did not record")
    missing = [k for k in ("robot", "seed", "house") if rec.get(k) is None]
    if missing:
        raise ResimError(f"the recording's result.json names no {', '.join(missing)}: not a hazard-detection run")
    if rec.get("drive", "statistical") not in ("statistical", "mechanical"):
        raise ResimError(f"the recorded drive {rec['drive']!r} is not one this build has")
    return {"robot": rec["robot"], "seed": rec["seed"], "house": rec["house"], "rtf": rec.get("rtf") or 0.0,
            "scheduled": rec.get("scheduled"), "command_at": rec.get("command_sim_s"),
            "disturbances": rec.get("disturbances"),
            "lived_in": _knobs(rec, "lived_in", LivedIn), "daylight": _knobs(rec, "daylight", Daylight),
            "link": _recorded_link(rec),
            "mechanical_drive": rec.get("drive") == "mechanical"}


def _knobs(rec: dict, key: str, cls):
    """The knobs of a recorded world change (result.json's lived_in or daylight: what changed, and `knobs`)."""
    from .resim import ResimError

    if not rec.get(key):
        return None
    knobs = rec[key].get("knobs") if isinstance(rec[key], dict) else None
    names = {f.name for f in fields(cls)}
    if not isinstance(knobs, dict) or set(knobs) - names:
        raise ResimError(f"the recording's {key} {json.dumps(rec[key])[:200]} does not name the knobs this build "
                         f"has ({', '.join(sorted(names))}): it cannot re-simulate that run")
    return cls(**knobs)


def _recorded_link(rec: dict) -> LinkFaults | None:
    """The link's faults as recorded (result.json's `link` also holds what the link did: LinkStats)."""
    from .resim import ResimError

    link = rec.get("link")
    if not link:
        return None
    faults, stats = {f.name for f in fields(LinkFaults)}, {f.name for f in fields(LinkStats)}
    if not isinstance(link, dict) or set(link) - faults - stats:
        raise ResimError(f"the recording's link {json.dumps(link)[:200]} names faults this build does not have")
    kw = {k: v for k, v in link.items() if k in faults}
    if "outages" in kw:
        kw["outages"] = tuple(tuple(o) for o in kw["outages"])
    try:
        return LinkFaults(**kw)
    except (TypeError, ValueError) as e:
        raise ResimError(f"the recording's link cannot be made again: {e}") from None


def link_faults(text: str) -> LinkFaults:
    try:
        return LinkFaults.parse(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def link_result(run: Run, owner: Owner, link: LinkFaults | None) -> dict | None:
    """The flaky link's faults as asked and what it did (None: a perfect link)."""
    relay = run.system.links.get(owner.handle.robot_id) if link and run.system and owner.handle else None
    return None if link is None else {**link.describe(), **(asdict(relay.stats) if relay else {})}


def schedule_owner(world, at: str):
    """(command, deliver, core_kw) of an owner who schedules the check at `at` (HH:MM, the robot's
    local time) instead of asking for it: the Core's clock is the world's, starting SCHEDULE_LEAD_S
    before `at` today, and runs ahead while the Core waits (agents/scheduler.py WorldClock)."""
    from datetime import datetime, timedelta

    from agents.scheduler import WorldClock
    from ontology.results import ScheduleEvent

    try:
        hour, minute = (int(x) for x in at.split(":"))
        first = datetime.now().astimezone().replace(hour=hour, minute=minute, second=0, microsecond=0)
    except ValueError:
        raise ValueError(f"--scheduled takes a time of day as HH:MM, not {at!r}") from None
    clock = WorldClock(world, first - timedelta(seconds=SCHEDULE_LEAD_S), fast_forward=True)
    command = f"{COMMAND} every day at {hour:02d}:{minute:02d}"

    async def deliver(owner: Owner) -> None:
        user, start = owner.handle.user, len(owner.handle.user.schedules)
        await user.say(owner.handle.core.address, command)
        told = await user.schedule_change(60, start)
        if told.event != ScheduleEvent.KEPT:
            raise RuntimeError(f"the Core did not keep the schedule ({told.event}): {told.reason}")

    return command, deliver, {"clock": clock}


def frame_counts(reports: list[ReportRecord], captures: int) -> dict:
    """Camera frames of the run: every capture the robot made (counted by the scenario), and the
    RApp's own count of its localizations' frames and of those in which no code was found (the
    closing report's `localization`, rapps/sdk/localize.py Localizer.stats)."""
    stats = next((r.data["localization"] for r in reversed(reports) if "localization" in r.data), {})
    return {"captured": captures, **stats}


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


def cm(value: float | None) -> str:
    return "n/a" if value is None else f"{value * 100:.1f} cm"


def summary(result: dict) -> str:
    verdict = ("INTERRUPTED" if "interrupted" in result["reason"] else "all correct" if result["all_correct"]
               else "MISCLASSIFIED" if result["finished"] else "DID NOT FINISH")
    lines = [f"hazard detection: robot {result['robot']} seed {result['seed']}: {verdict}, "
             f"localization {cm(result['localization_error_m'])}, "
             f"tracking {cm(result['max_tracking_error_m'])}, "
             f"{result['duration_sim_s']:.0f} s sim / {result['duration_wall_s']:.0f} s wall"
             + (" (started by its schedule)" if result.get("trigger") == "scheduled" else "")]
    f = result.get("frames") or {}
    if f.get("frames"):
        lines.append(f"  frames: {f['captured']} captured; localization {f['frames']} in {f['localizations']} "
                     f"localizations ({f['frames_per_localization']} each), {f['frames_without_code']} without a code "
                     f"({f['no_code_share'] * 100:.0f} %)")
    if not result["ok"]:
        lines.append(f"  {result['reason']}")
    for h in result["hazards"]:
        extra = (f" (true {h['true_angle']:.0f} deg, estimated {h['estimated_angle']})" if h["type"] == "door" else "")
        lines.append(f"  {h['type']:4s} {h['id']:10s} true {h['true_state']:6s} reported {h['reported_state']}{extra}")
    if result["strategies"] or result["replans"] or result["estops"]:
        lines.append(f"  safety: {result['estops']} stops, strategies {', '.join(sorted(set(result['strategies']))) or '-'}"
                     f", {result['replans']} replans, {result['obstacles_marked']} obstacles marked")
    out = Path(result["trace"]).parent
    lines.append(f"  wrote in {out}: {files_written(out)}")
    return "\n".join(lines)


# the options a re-simulation takes from the recording instead (--replay refuses them)
REPLAY_SETS = ("robot", "seed", "house", "rtf", "scheduled", "realism", "mechanical_drive", "daylight", "lived_in", "link")


def recorded_package(run_dir) -> Path | None:
    """The hazard RApp's package the recorded run ran (packages/), None if it kept none."""
    from rapps.replay import RecordingError, load_recording

    try:
        return load_recording(run_dir).package
    except RecordingError:
        return None


def describe_settings(settings: dict) -> str:
    knobs = [k for k in ("lived_in", "link", "daylight") if settings.get(k) is not None]
    knobs += ["mechanical drive"] if settings.get("mechanical_drive") else []
    knobs += ["disturbances"] if settings.get("disturbances") else []
    knobs += [f"scheduled at {settings['scheduled']}"] if settings.get("scheduled") else []
    return (f"re-simulating {settings['robot']} seed {settings['seed']} in {settings['house']}"
            + (f", command at {settings['command_at']:.2f} s simulated" if settings.get("command_at") is not None else "")
            + f"; realism: {', '.join(k.replace('_', '-') for k in knobs) or 'none'}; "
            + (f"the recorded package {settings['rapp'].name}" if settings.get("rapp")
               else f"no package kept: the RApp of {RAPP_DIR}"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="rapp run hazard-detection", description=__doc__.split("\n\n")[0].replace("\n", " "))
    ap.add_argument("--robot", choices=ROBOTS, default="nao", help="the simulated robot (default nao)")
    ap.add_argument("--seed", type=int, default=1, help="draws the world: door angles, lamps, a generated house "
                                                        "(docs/sdk.md 'Scoring against the truth')")
    ap.add_argument("--house", choices=HOUSES, default="house",
                    help="a hand-made house, or 'generated': the house generated from --seed")
    ap.add_argument("--json", dest="json_path", default=None, help="write the result JSON here (default: OUT/result.json)")
    ap.add_argument("--out", dest="out_dir", default=None, help="directory for result, plot, frames, chat and trace "
                                                                 "(default: a new temporary directory)")
    ap.add_argument("--rtf", type=float, default=0.0, help="real-time factor (0 = as fast as possible)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds to wait for the RApp's end")
    ap.add_argument("--quiet", action="store_true", help="no progress while it runs, only the closing summary")
    ap.add_argument("--plain", action="store_true", help="progress as plain lines, even on a terminal")
    add_recording_options(ap)
    ap.add_argument("--scheduled", nargs="?", const="22:00", metavar="HH:MM",
                    help="started by a schedule, not a command: the owner writes 'check the hazards every day at "
                         "HH:MM' (default 22:00) and the robot's simulated clock comes to it")
    ap.add_argument("--realism", choices=REALISM, default="none",
                    help="'full': every realism knob on (--lived-in, --daylight random, --mechanical-drive and a --link of "
                         + FULL_LINK.replace("%", "%%") + "; docs/realism.md)")
    ap.add_argument("--mechanical-drive", action="store_true",
                    help="the NAO's body moves by steps, the Elektron's by its two wheel sides, each slipping "
                         "(robots/failure_modes.py); default: even motion with statistical slip")
    ap.add_argument("--daylight", type=daylight_arg, default=None, metavar="TIME",
                    help="the light of a time of day ('random', HH:MM or hours): windows by day, lamps of several "
                         "strengths (seeded by --seed; robots/lighting.py); default: the studio light")
    ap.add_argument("--lived-in", action="store_true",
                    help="the house changed since its map was made: furniture moved, boxes left, a passage door "
                         "half closed, a rug (seeded by --seed; robots/lived_in.py)")
    ap.add_argument("--link", type=link_faults, default=None, metavar="FAULTS",
                    help="the robot's connection to the server is flaky, e.g. "
                         "'delay=80ms,jitter=30ms,loss=2%%,outage=5s@40s,drop' (seeded by --seed; "
                         "xmpp_server/link.py); every agent then talks over the server")
    args = ap.parse_args(argv)
    if args.replay:
        from .resim import ResimError, recorded_result
        given = [f"--{k.replace('_', '-')}" for k in REPLAY_SETS if getattr(args, k) != ap.get_default(k)]
        if given:
            ap.error(f"--replay runs the recording's world again: {', '.join(given)} cannot be given with it")
        try:
            settings = recorded_settings(recorded_result(args.replay))
        except ResimError as exc:
            print(f"rapp run hazard-detection: cannot re-simulate {args.replay}: {exc}", file=sys.stderr)
            return 2
        args.robot = settings["robot"]
        settings["rapp"] = recorded_package(args.replay)
        print(f"[resim] {describe_settings(settings)}", flush=True)
    else:
        settings = {"robot": args.robot, "seed": args.seed, "house": args.house, "rtf": args.rtf,
                    "scheduled": args.scheduled, **realism(args.realism, args.seed, args.lived_in, args.link,
                                                           args.daylight, args.mechanical_drive)}
    try:
        result = main_loop(run_hazard_detection(json_path=args.json_path, out_dir=args.out_dir, timeout_s=args.timeout,
                                                progress=not args.quiet, live=False if args.plain else None,
                                                record=not args.no_record, frames=not args.no_frames, **settings))
    except RunInterrupted as stop:
        if stop.result:
            print(summary(stop.result))
        return 128 + stop.signum
    print(summary(result))
    if args.replay:
        from . import resim
        out = Path(result["trace"]).parent
        comparison = resim.compare(args.replay, out, args.robot, args.tolerance or resim.TRAJECTORY_TOL_M)
        print(comparison.text())
        print(f"  compared in {resim.write(out, args.replay, comparison)}")
        return 0 if comparison.ok else 1
    return 0 if result["all_correct"] and result["finished"] else 1


if __name__ == "__main__":
    sys.exit(main())
