"""`rapp run rapp DIR_OR_PACKAGE --robot nao|elektron --house NAME_OR_FILE [--seed S] [--say TEXT]`:
run your own RApp on a simulated robot, as the hazard scenario runs its RApp.

Builds the package (when given a directory; signed with a key of this run), publishes it to a fresh
Store on the embedded server, uploads the house's home description and map for the owner, sends
the owner's command (default: the RApp's first keyword) and waits until the RApp ends. Writes
result.json (the RApp's reports as data, how it ended, and the world's truth to score it against),
chat.txt, trace.jsonl, run.png (the map, the robot's whole true trajectory, its planned legs and
localizations), frames/ (every image the RApp captured) and outputs/ (the files the RApp wrote to its
Task.outputs) to --out; exits 1 with the reason on one line when the RApp ends in error, 128 + the
signal when interrupted (Ctrl-C, SIGTERM: the files are written with what is known).

While it runs: a live panel on a terminal (Core and RApp states, pose, progress, chat), plain lines
otherwise or with --plain, nothing with --quiet; --watch [PORT] serves a live page of the map, robot,
planned path and camera on http://127.0.0.1:PORT/ (default 8765).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
from pathlib import Path

from agents.sandbox import allow_unsandboxed, copy_outputs
from agents.tracing import read_trace
from ontology import robot_types
from ontology.results import TaskStage
from ontology.trace import RecordKind, StructureEvent
from robots import RobotAPI
from scenarios.home_setup import has_layout, home_description, scenario_world
from scenarios.owner_voice import OwnerVoice, ScriptError, SpokenLine, announce_run, load_script, retire_run
from scenarios.plots import plot_hazard_run
from scenarios.progress import RunView
from scenarios.recorder import RecordingAPI
from scenarios.runner import (Owner, Run, RunInterrupted, add_recording_options, check_interrupted, files_written, main_loop, plot_grid,
                              saving)
from scenarios.system import wait_until
from scenarios.watch import DEFAULT_PORT, WatchServer, WatchState

ROBOTS = robot_types.names()  # ontology/robot_types.py


def _copy_outputs(records: list[dict], core: str, dest: Path) -> list[str]:
    """The RApp's output directory (Task.outputs, named by the Core's destroy record) copied to dest:
    the RApp's to fill, so copied as agents/sandbox.py copy_outputs does (regular files only, no link
    followed, size-capped; what it left out is said, and never fails the run)."""
    kept = [r.get("outputs") for r in records if r["kind"] == RecordKind.STRUCTURE and r.get("agent") == core
            and r.get("event") == StructureEvent.DESTROY and r.get("outputs") and not r.get("origin")]
    if not kept:
        return []
    copied, skipped = copy_outputs(kept[-1], dest)
    for why in skipped:
        print(f"[outputs] not copied: {why}", flush=True)
    return sorted(copied)


async def run_rapp(src: Path, robot: str, house: str, seed: int, say: str | None, out: Path,
                   timeout_s: float, progress: bool = False, live: bool | None = None,
                   watch_port: int | None = None, speak: bool = False,
                   script: list[SpokenLine] | None = None, listen: bool = False,
                   disturbances: str | Path | None = None, record: bool = True, frames: bool = True,
                   command_at: float | None = None) -> dict:
    """`progress`: show it (`live`: the rich panel, None = on a terminal, else plain lines);
    `watch_port`: serve the live page there (0 = any free port); `speak`: the owner says the command
    aloud instead of typing it; `script`: lines the owner says at their times; `listen`: no command
    is sent, the owner's voice gives it; `disturbances`: a scenario file's people, doors and boxes
    (robots/disturbances.py); `record`: the run's recording and run.mcap (`frames`: with the camera's
    frames; docs/recordings.md); `command_at`: the simulated time the command is given at (a
    re-simulation's, scenarios/resim.py). While it runs, `rapp say TEXT` is heard too (the run's inbox)."""
    out = Path(out)
    world = scenario_world(house, seed, disturbances=disturbances)
    watch: WatchServer | None = None
    view = RunView()
    voice_tasks: list[asyncio.Task] = []
    outputs: list[str] = []
    try:
        # every image the RApp captures is kept in out/frames; legs and localizations are recorded
        api = RecordingAPI(RobotAPI(world.add_robot(robot)), frames_dir=out / "frames", every_capture=True)
        if watch_port is not None:
            watch = WatchServer(WatchState(plot_grid(world, house), pose=lambda: api.robot.pose, recorder=api,
                                           view=view, title=f"{src.name} on {robot} in {house}"), port=watch_port)
            print(f"[watch] {await watch.start()}", flush=True)
        name = Path(house).stem
        home = home_description(world, name, out) if has_layout(name, world) else None
        voice = OwnerVoice(world, api, out)
        owner = Owner(robot, api, f"owner-{robot}1", None, home=home, command_at=command_at)
        run = Run(out, world, src, [owner], record=record, frames=frames, grid=plot_grid(world, house))

        async def before(run: Run) -> None:
            owner.command = None if listen else say or run.keywords[0]
            if speak or script or listen:
                voice.check()
                # once the Core's ear is open and has measured the room's noise floor
                await wait_until(lambda: "audio-listener" in owner.handle.core.active_behaviours(), 60,
                                 "the Core's audio listener")
                await world.sleep(1.5)
            announce_run(out)
            voice_tasks.extend([asyncio.create_task(voice.serve_inbox()),
                                asyncio.create_task(voice.run_script(script or []))])

        async def deliver(owner: Owner) -> None:
            if listen:  # the command comes by voice: `rapp say` or the scenario's speech lines
                print(f"[run] {robot} in {house}: listening; speak with `rapp say TEXT`", flush=True)
            elif speak:
                await voice.speak(SpokenLine(say=owner.command))
            else:
                if progress:  # --quiet: nothing until the closing summary
                    print(f"[run] {robot} in {house}: owner says {owner.command!r}", flush=True)
                await owner.handle.user.say(owner.handle.core.address, owner.command)
        owner.deliver = deliver

        async def after(run: Run) -> None:  # the RApp's files: before the Core's work directory goes
            records = await asyncio.to_thread(read_trace, out / "trace.jsonl")
            outputs.extend(await asyncio.to_thread(_copy_outputs, records, owner.handle.core.address, out / "outputs"))

        show = None
        if progress or watch is not None:  # from the trace: Core and RApp states, chat, the robot's pose
            show = dict(pose=lambda: api.robot.pose, live=live, view=view, silent=not progress,
                        title=f"rapp run {src.name}")
        # listening, a misheard line is answered "Sorry" and the owner says it again: only a task's end ends it
        await run.run(timeout_s, show=show, before=before, after=after,
                      accept=(lambda r: r.stage != TaskStage.UNDERSTAND) if listen else None)
        with saving():
            rec, ok = owner.record, run.ok(owner)
            plot = await asyncio.to_thread(
                plot_hazard_run, out / "run.png", plot_grid(world, house), api.paths, api.localizations, {}, [], [],
                title=f"{run.name or src.name} on {robot} in {house}, seed {seed}: "
                      f"{'finished' if ok else run.interrupted or 'error'}",
                trajectory=[p[1:3] for p in run.trajectories[robot]])
            result = {"rapp": run.name, "robot": robot, "house": house, "seed": seed, "command": owner.command,
                      "delivery": "listen" if listen else "speech" if speak else "chat",
                      "command_sim_s": owner.given_at,
                      "scenario": str(disturbances) if disturbances else None,
                      "spoken": voice.spoken, "person_contacts": world.person_contacts(),
                      "object_contacts": world.object_contacts(),
                      "ok": ok, "end": run.end_text(owner), "reason": run.reason(owner),
                      "stage": rec.stage.value if rec else None, "state": rec.state if rec else None,
                      "reports": [r.model_dump() for r in owner.reports],
                      "refusals": [r.model_dump() for r in rec.refusals] if rec else [],
                      "started": rec.started if rec else None, "ended": rec.ended if rec else None,
                      "duration_sim_s": round(run.sim_s, 2), "duration_wall_s": round(run.wall_s, 2),
                      "trace": str(out / "trace.jsonl"), "plot": str(plot), "frames": [str(f) for f in api.frames],
                      "outputs": outputs, "truth": run.truth()}
            (out / "chat.txt").write_text("\n".join(owner.transcript) + "\n")
            (out / "result.json").write_text(json.dumps(result, indent=1))
            await run.finish_recording()
        check_interrupted(result)
        return result
    finally:
        for task in voice_tasks:
            task.cancel()
        retire_run(out)
        if watch is not None:
            await watch.stop()
        world.close()


def closing_summary(result: dict, out: Path) -> str:
    verdict = "finished" if result["ok"] else "INTERRUPTED" if "interrupted" in result["reason"] else "ERROR"
    lines = [f"{result['rapp']}: {verdict}: {result['end']}"]
    if result["reports"]:
        lines.append(f"  {len(result['reports'])} reports; {len(result['frames'])} frames captured; "
                     f"{len(result['outputs'])} output files")
    lines.append(f"  wrote in {out}: {files_written(out)}")
    lines.append(f"  result {out / 'result.json'}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="rapp run rapp", description=__doc__.split("\n\n")[0].replace("\n", " "))
    p.add_argument("rapp", nargs="?", help="a RApp source directory (with manifest.yaml) or a built .rapp package "
                                           "(with --replay: default the recorded package)")
    p.add_argument("--robot", choices=ROBOTS, default="nao", help="the simulated robot (default nao)")
    p.add_argument("--house", default="small", help="house name (small, house, twodoors, generated with --seed) "
                                                     "or YAML file")
    p.add_argument("--seed", type=int, default=1, help="draws the world (door angles, lamps; docs/sdk.md "
                                                        "'Scoring against the truth')")
    p.add_argument("--say", help="the owner's command (default: the RApp's first keyword)")
    p.add_argument("--out", help="result folder (default: a new temporary directory)")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds to wait for the RApp's end")
    p.add_argument("--quiet", action="store_true", help="no progress while it runs, only the closing summary")
    p.add_argument("--plain", action="store_true", help="progress as plain lines, even on a terminal")
    p.add_argument("--watch", nargs="?", type=int, const=DEFAULT_PORT, default=None, metavar="PORT",
                   help=f"serve a live page on http://127.0.0.1:PORT/ (default {DEFAULT_PORT})")
    p.add_argument("--speak", action="store_true", help="the owner says the command aloud (the robot hears it "
                                                         "through its microphone; needs the speech extra)")
    p.add_argument("--scenario", metavar="FILE", help="a scenario file: its `speech:` lines are said at their "
                                                       "times, its `disturbances:` (people, doors, boxes) happen")
    p.add_argument("--listen", action="store_true", help="send no command: the owner gives it by voice "
                                                          "(`rapp say TEXT` while it runs, or --scenario lines)")
    p.add_argument("--allow-unsandboxed", action="store_true",
                   help="run the RApp without the sandbox where the kernel allows none (the reason is printed)")
    add_recording_options(p)
    a = p.parse_args(argv)
    if not allow_unsandboxed(a.allow_unsandboxed, "rapp run rapp"):
        return 2
    if a.replay:
        try:
            a = _from_recording(a, p)
        except ValueError as exc:
            print(f"rapp run rapp: {exc}", file=sys.stderr)
            return 2
    if a.rapp is None:
        p.error("the RApp (a folder or package) is needed, or --replay RUN_DIR")
    src = Path(a.rapp)
    if not src.exists():
        print(f"rapp run rapp: {src} does not exist", file=sys.stderr)
        return 2
    try:
        script = load_script(a.scenario) if a.scenario else None
    except ScriptError as exc:
        print(f"rapp run rapp: {exc}", file=sys.stderr)
        return 2
    out = Path(a.out or tempfile.mkdtemp(prefix="rapp-run-"))
    out.mkdir(parents=True, exist_ok=True)
    code = 0
    try:
        result = main_loop(run_rapp(src, a.robot, a.house, a.seed, a.say, out, a.timeout, progress=not a.quiet,
                                    live=False if a.plain else None, watch_port=a.watch, speak=a.speak,
                                    script=script, listen=a.listen, disturbances=a.scenario,
                                    record=not a.no_record, frames=not a.no_frames,
                                    command_at=getattr(a, "command_at", None)))
    except ScriptError as exc:
        print(f"rapp run rapp: {exc}", file=sys.stderr)
        return 2
    except RunInterrupted as stop:
        if not stop.result:
            print(f"rapp run rapp: {stop} before the run began", file=sys.stderr)
            return 128 + stop.signum
        result, code = stop.result, 128 + stop.signum
    print(closing_summary(result, out))
    if a.replay and not code:
        from scenarios import resim
        comparison = resim.compare(a.replay, out, a.robot, a.tolerance or resim.TRAJECTORY_TOL_M)
        print(comparison.text())
        print(f"  compared in {resim.write(out, a.replay, comparison)}")
        return 0 if comparison.ok else 1
    return code or (0 if result["ok"] else 1)


def _from_recording(a, p) -> argparse.Namespace:
    """A re-simulation's settings: the recorded run's robot, house, seed, command, how it was given
    (typed, said aloud, or by voice to a listening robot) and its time, scenario file, and (no RApp
    given) its recorded package."""
    from scenarios.resim import recorded_result

    rec = recorded_result(a.replay)
    given = {k for k in ("robot", "house", "seed", "say") if getattr(a, k) != p.get_default(k)}
    for key, field in (("robot", "robot"), ("house", "house"), ("seed", "seed"), ("say", "command")):
        if key not in given and rec.get(field) is not None:
            setattr(a, key, rec[field])
    if a.scenario is None and rec.get("scenario"):
        a.scenario = rec["scenario"]
    delivery = rec.get("delivery", "chat")
    if delivery not in ("chat", "speech", "listen"):
        raise ValueError(f"{a.replay}: the command came by {delivery!r}, which this build cannot give again")
    if delivery == "listen" and not a.scenario:
        raise ValueError(f"{a.replay}: the owner gave the command by voice while it listened (`rapp say`), "
                         "which a re-simulation cannot say again; a --scenario file's speech lines can")
    a.speak, a.listen = a.speak or delivery == "speech", a.listen or delivery == "listen"
    a.command_at = rec.get("command_sim_s")
    if a.rapp is None:
        from rapps.replay import load_recording
        package = load_recording(a.replay).package
        if package is None:
            raise ValueError(f"{a.replay} kept no package: give the RApp's folder")
        a.rapp = str(package)
    if given:
        print(f"[resim] given, not the recording's: {', '.join(sorted(given))}", flush=True)
    return a
