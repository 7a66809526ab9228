"""`rapp run rapp DIR_OR_PACKAGE --robot nao|elektron --house NAME_OR_FILE [--seed S] [--say TEXT]`:
run your own RApp on a simulated robot, as the hazard scenario runs its RApp.

Builds the package (when given a directory; signed with a key of this run), publishes it to a fresh
Store on the embedded server, uploads the house's home description and map for the owner, sends
the owner's command (default: the RApp's first keyword) and waits until the RApp ends. Writes
result.json (the RApp's reports as data), chat.txt, trace.jsonl, run.png (the map, the robot's
whole true trajectory, its planned legs and localizations), frames/ (every image the RApp
captured) and outputs/ (the files the RApp wrote to its Task.outputs) to --out; exits 1 with the reason on one line when the RApp ends in error.

While it runs: a live panel on a terminal (Core and RApp states, pose, progress, chat), plain lines
otherwise or with --quiet; --watch [PORT] serves a live page of the map, robot, planned path and
camera on http://127.0.0.1:PORT/ (default 8765).
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
from ontology.manifest import load_manifest
from ontology.trace import Direction, RecordKind, StructureEvent
from robots import RobotAPI, World
from robots.gridmap import build_grid_map
from scenarios.home_setup import has_layout, home_description, home_map, upload_home
from scenarios.owner_voice import OwnerVoice, ScriptError, SpokenLine, announce_run, load_script, retire_run
from scenarios.plots import plot_hazard_run
from scenarios.progress import RunView, follow
from scenarios.recorder import RecordingAPI
from scenarios.system import RappSystem, wait_until
from scenarios.watch import DEFAULT_PORT, WatchServer, WatchState


def _reports(records: list[dict], core: str) -> list[dict]:
    """What the RApp reported (text and data), from the trace: its requests to the Core."""
    out = []
    for r in records:
        if (r["kind"] == RecordKind.MESSAGE and r["dir"] == Direction.RECV and r["agent"] == core
                and r["action"] == "report"):
            try:
                out.append(json.loads(r["content"]))
            except ValueError:
                out.append({"text": r["content"]})
    return out


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


async def _sample_poses(api, into: list, period_s: float = 0.2) -> None:
    """The robot's true (x, y) through the whole run, for the plot (simulation time)."""
    while True:
        into.append(tuple(api.robot.pose[:2]))
        await api.world.sleep(period_s, drive=False)  # observe; never run the world ahead


def _grid(world, house: str):
    return home_map(world, Path(house).stem) if has_layout(Path(house).stem, world) else build_grid_map(world.plan)


def _plot(out: Path, world, house: str, recorder: RecordingAPI, trajectory: list, title: str) -> Path:
    return plot_hazard_run(out / "run.png", _grid(world, house), recorder.paths, recorder.localizations, {}, [], [],
                           title=title, trajectory=trajectory)


async def run_rapp(src: Path, robot: str, house: str, seed: int, say: str | None, out: Path,
                   timeout_s: float, progress: bool = False, live: bool | None = None,
                   watch_port: int | None = None, speak: bool = False,
                   script: list[SpokenLine] | None = None, listen: bool = False,
                   disturbances: str | Path | None = None) -> dict:
    """`progress`: show it (`live`: the rich panel, None = on a terminal, else plain lines);
    `watch_port`: serve the live page there (0 = any free port); `speak`: the owner says the command
    aloud instead of typing it; `script`: lines the owner says at their times; `listen`: no command
    is sent, the owner's voice gives it; `disturbances`: a scenario file's people, doors and boxes
    (robots/disturbances.py). While it runs, `rapp say TEXT` is heard too (the run's inbox)."""
    manifest_dir = src if src.is_dir() else None
    world = World.from_file(house, seed=seed, disturbances=disturbances)
    trajectory: list = []
    sampler: asyncio.Task | None = None
    watch: WatchServer | None = None
    view = RunView()
    voice_tasks: list[asyncio.Task] = []
    try:
        # every image the RApp captures is kept in out/frames; legs and localizations are recorded
        api = RecordingAPI(RobotAPI(world.add_robot(robot)), frames_dir=out / "frames", every_capture=True)
        sampler = asyncio.create_task(_sample_poses(api, trajectory))
        if watch_port is not None:
            watch = WatchServer(WatchState(_grid(world, house), pose=lambda: api.robot.pose, recorder=api,
                                           view=view, title=f"{src.name} on {robot} in {house}"), port=watch_port)
            print(f"[watch] {await watch.start()}", flush=True)
        async with RappSystem(out / "system", trace_file=out / "trace.jsonl") as system:
            if manifest_dir is not None:
                name = (await system.publish(src)).split()[0]
                keywords = load_manifest(src).keywords
            else:  # a built package: published as it is (the Cores then need --allow-unsigned)
                from agents.store_client import publish_package
                from ontology.store import RegisterOwner
                from ontology.package import read_package
                pkg = read_package(src.read_bytes())
                name, keywords = pkg.manifest.name, pkg.manifest.keywords
                await system.publisher.request(system.store.address, RegisterOwner(owner="developer",
                                                                                   password="developer-secret"))
                await publish_package(system.publisher, system.store.address, "developer", "developer-secret",
                                      src.read_bytes())
            user = f"owner-{robot}1"
            if has_layout(Path(house).stem, world):  # the owner's home description, as the Platform keeps it
                info, png, yaml_text = home_description(world, Path(house).stem, out)
                upload_home(system.platform.state, user, info, png, yaml_text)
            if progress or watch is not None:  # from the trace: Core and RApp states, chat, the robot's pose
                follower = asyncio.create_task(follow(out / "trace.jsonl", pose=lambda: api.robot.pose, live=live,
                                                      view=view, silent=not progress, title=f"rapp run {name}"))
                system.on_stop(follower.cancel)
            kw = {} if manifest_dir is not None else {"require_signature": False, "trusted_keys": None}
            handle = await system.add_robot(robot, api=api, user=user, **kw)
            await wait_until(lambda: handle.core.supervisor.behaviour.current == "s3_listen", 30, "Core listening")
            command = None if listen else say or keywords[0]
            voice = OwnerVoice(world, api, out)
            if speak or script or listen:
                voice.check()
                # once the Core's ear is open and has measured the room's noise floor
                await wait_until(lambda: "audio-listener" in handle.core.active_behaviours(), 60,
                                 "the Core's audio listener")
                await world.sleep(1.5)
            announce_run(out)
            voice_tasks += [asyncio.create_task(voice.serve_inbox()), asyncio.create_task(voice.run_script(script or []))]
            start = len(handle.user.received)
            if listen:  # the command comes by voice: `rapp say` or the scenario's speech lines
                print(f"[run] {robot} in {house}: listening; speak with `rapp say TEXT`", flush=True)
            elif speak:
                await voice.speak(SpokenLine(say=command))
            else:
                print(f"[run] {robot} in {house}: owner says {command!r}", flush=True)
                await handle.user.say(handle.core.address, command)
            end = await handle.user.wait_for(  # listening: a misheard line is answered "Sorry", the owner says it again
                lambda t: t.startswith((f"{name} finished", f"{name} ended")) or (t.startswith("Sorry") and not listen)
                or "could not get" in t or "did not start" in t, timeout=timeout_s, start=start)
            texts = handle.user.texts()[start:]
            records = await asyncio.to_thread(read_trace, out / "trace.jsonl")
            reports = _reports(records, handle.core.address)
            outputs = await asyncio.to_thread(_copy_outputs, records, handle.core.address, out / "outputs")
        sampler.cancel()
        refused = list(handle.core.last_refusals)  # told, not hidden: a refused RApp is no success
        ok = end.startswith(f"{name} finished") and not refused
        plot = await asyncio.to_thread(_plot, out, world, house, api, trajectory, f"{name} on {robot} in {house}, "
                                       f"seed {seed}: {'finished' if ok else 'error'}")
        result = {"rapp": name, "robot": robot, "house": house, "seed": seed, "command": command,
                  "spoken": voice.spoken, "person_contacts": world.person_contacts(),
                  "object_contacts": world.object_contacts(),
                  "ok": ok, "end": end, "reports": reports, "trace": str(out / "trace.jsonl"),
                  "plot": str(plot), "frames": [str(f) for f in api.frames], "outputs": outputs,
                  "refusals": refused}
        (out / "chat.txt").write_text("\n".join(handle.user.transcript(start, handle.core.address)) + "\n")
        (out / "result.json").write_text(json.dumps(result, indent=1))
        return result
    finally:
        for task in voice_tasks:
            task.cancel()
        retire_run(out)
        if sampler is not None:
            sampler.cancel()
        if watch is not None:
            await watch.stop()
        world.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="rapp run rapp", description=__doc__.splitlines()[0])
    p.add_argument("rapp", help="a RApp source directory (with manifest.yaml) or a built .rapp package")
    p.add_argument("--robot", choices=["nao", "elektron"], default="nao")
    p.add_argument("--house", default="small", help="house name (small, house, generated with --seed) or YAML file")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--say", help="the owner's command (default: the RApp's first keyword)")
    p.add_argument("--out", help="result folder (default: a new temporary directory)")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds to wait for the RApp's end")
    p.add_argument("--quiet", action="store_true", help="plain progress lines, not the live panel")
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
    a = p.parse_args(argv)
    if not allow_unsandboxed(a.allow_unsandboxed, "rapp run rapp"):
        return 2
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
    try:
        result = asyncio.run(run_rapp(src, a.robot, a.house, a.seed, a.say, out, a.timeout, progress=True,
                                      live=False if a.quiet else None, watch_port=a.watch, speak=a.speak,
                                      script=script, listen=a.listen, disturbances=a.scenario))
    except ScriptError as exc:
        print(f"rapp run rapp: {exc}", file=sys.stderr)
        return 2
    print(f"{result['rapp']}: {'finished' if result['ok'] else 'ERROR'}: {result['end']}")
    print(f"  result {out / 'result.json'}; chat {out / 'chat.txt'}; trace {out / 'trace.jsonl'}")
    print(f"  plot {result['plot']}; {len(result['frames'])} frames captured"
          + (f" in {out / 'frames'}" if result["frames"] else ""))
    if result["outputs"]:
        print(f"  outputs: {len(result['outputs'])} files in {out / 'outputs'}")
    return 0 if result["ok"] else 1
