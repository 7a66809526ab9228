"""`rapp`: one command line for the project. Errors are one line unless --debug.

    rapp server [--host H] [--port P] [--domain D] [--db FILE | --memory]
    rapp agent store|platform|core [...]       (one agent on this machine, for deployments)
    rapp new NAME [DIR] [--cloud]              (a RApp package to start from)
    rapp run SCENARIO [...]                    (rapp run --help lists them; rapp run SCENARIO --help)
    rapp run rapp DIR_OR_PACKAGE --robot nao|elektron --house NAME [--say TEXT] [--speak] [--scenario FILE]
    rapp test DIR                              (a RApp's tests, with what `pip install -e .` installs)
    rapp say TEXT [--run DIR] [--distance M] [--voice V]   (the owner speaks into a running `rapp run`)
    rapp package build DIR [-o OUT] [--key KEY.pem] | rapp package keygen KEY.pem
    rapp store publish FILE --owner O --password P | list [--robot-type T] | info NAME | remove NAME
    rapp store builds [NAME] | log NAME --robot-type T [--version V] | serve [--port P]   (builds; a page)
    rapp platform upload-home --house H --user U --password P
    rapp house check FILE [-o PNG] [--seed N] | rapp house new NAME [-o FILE]   (house files: docs/houses.md)
    rapp trace show|export|html FILE [...]      (rapp trace FILE = show: a summary; --view, --limit)
    rapp trace export --format mcap RUN_DIR [-o FILE] [--no-frames]   (run.mcap of a run folder)
    rapp replay RUN_DIR [--rapp DIR] [--run N]  (a recorded RApp run again, against the recorded answers)
    rapp bench [--quick] [--json FILE]
    rapp doctor
"""
from __future__ import annotations

import argparse
import asyncio
import faulthandler
import sys
from pathlib import Path


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 1."""


# -- server -----------------------------------------------------------------------------------
def cmd_server(a) -> int:
    import contextlib

    from xmpp_server.__main__ import main as server_main

    argv = ["--host", a.host, "--port", str(a.port), "--domain", a.domain]
    with contextlib.ExitStack() as stack:
        if a.memory:
            kind = "in-memory database"
        else:
            db = a.db or _scratch_db(stack)
            argv += ["--db", db]
            kind = f"database {db}" + ("" if a.db else ", removed when it stops (--db FILE keeps one)")
        print(f"embedded XMPP server on {a.host}:{a.port}, domain {a.domain} ({kind}); Ctrl-C stops it",
              file=sys.stderr, flush=True)
        return server_main(argv + (["--verbose"] if a.verbose else []))


def _scratch_db(stack) -> str:
    """A database of this run only, removed when the server stops: a new start never read the last
    one's (each start used to leave its directory in /tmp)."""
    import tempfile
    return str(Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="rapp-xmpp-"))) / "server.db")


# -- run --------------------------------------------------------------------------------------
SCENARIOS = {  # name: (module with main(argv), what it runs)
    "rapp": ("scenarios.run_rapp", "your own RApp on a simulated robot: rapp run rapp DIR --robot nao --house small"),
    "hazard-detection": ("scenarios.hazard", "the paper's experiment: a robot checks a home's doors and lamps, "
                                             "scored against the truth"),
    "hazard-table": ("scenarios.hazard_table", "the experiment over houses, seeds and both robots, judged against "
                                               "the paper's figures"),
    "two-robots": ("scenarios.two_robots", "a NAO and an Elektron in one house, one Platform and Store"),
    "disturbances": ("scenarios.disturbance_suite", "the hazard RApp against people, doors and boxes in its way"),
    "demo": ("scenarios.demo", "two agents on the embedded XMPP server, three requests and their trace"),
}


def cmd_run(a, rest: list[str]) -> int:
    if a.scenario not in SCENARIOS:
        raise CliError(f"unknown scenario {a.scenario!r} (known: {', '.join(SCENARIOS)})")
    import importlib
    return importlib.import_module(SCENARIOS[a.scenario][0]).main(rest)


def _scenario_list() -> str:
    width = max(map(len, SCENARIOS))
    return "scenarios (rapp run SCENARIO --help for each one's options):\n" + "\n".join(
        f"  {name:{width}}  {what}" for name, (_, what) in SCENARIOS.items()) + (
        "\n\nA run of rapp, hazard-detection, two-robots or disturbances writes result.json (ok, reason, what "
        "happened, the world's truth),\nchat, trace and a plot in its --out folder; Ctrl-C or SIGTERM ends it with "
        "those files written (ok: false)\nand exit code 128 + the signal.")


# -- test -------------------------------------------------------------------------------------
def cmd_test(a, rest: list[str]) -> int:
    """A RApp's tests with the base install (pytest and pytest-asyncio are dependencies of the
    project): its own rootdir, no configuration of the checkout it may sit in, async tests run
    without marks, nothing cached into the RApp's folder; as the Store's build runs them
    (agents/store_build.py), `--robot` for one robot type (RAPP_ROBOT_TYPE)."""
    import os

    import pytest

    from agents.store_build import pytest_args

    target = Path(a.dir)
    if not target.exists():
        raise CliError(f"no RApp folder {target}")
    if a.robot:
        os.environ["RAPP_ROBOT_TYPE"] = a.robot
    return int(pytest.main([*pytest_args(target), *rest]))


# -- package ----------------------------------------------------------------------------------
def cmd_package(a) -> int:
    from ontology.package import build_package, generate_keypair, private_key_to_pem, public_key_id

    if a.action == "schema":  # the manifest's JSON Schema, from its model
        import json

        from ontology.manifest import manifest_schema
        text = json.dumps(manifest_schema(), indent=2) + "\n"
        if a.output or a.dir:
            Path(a.output or a.dir).write_text(text)
        else:
            print(text, end="")
        return 0
    if a.dir is None:
        raise CliError(f"rapp package {a.action} needs a directory or file")
    if a.action == "build":
        out = build_package(a.dir, a.output, signing_key=a.key)
        print(out)
        return 0
    if a.action == "keygen":
        key, pub = generate_keypair()
        Path(a.dir).write_bytes(private_key_to_pem(key))
        Path(a.dir).chmod(0o600)
        print(f"private key {a.dir}; public key {pub} (id {public_key_id(pub)})")
        return 0
    raise CliError(f"unknown package action {a.action!r}")


# -- new --------------------------------------------------------------------------------------
def cmd_new(a) -> int:
    from rapps.scaffold import create

    try:
        dest = create(a.name, a.dir, cloud=a.cloud)
    except (ValueError, FileExistsError) as e:
        raise CliError(str(e)) from None
    print(f"created {dest}: try  rapp run rapp {dest}  and  rapp test {dest}")
    return 0


# -- store ------------------------------------------------------------------------------------
async def _with_client(fn, account: tuple[str, str] | None = None):
    """Run `fn(client, settings)` with a client agent: logged in as `account` (name, password),
    e.g. a Store owner's own account, or else as a throwaway account deleted afterwards."""
    from agents.base import RappAgent
    from xmpp_server.settings import XmppSettings
    import uuid

    from xmpp_server.credentials import generate_password
    from xmpp_server.probe import LoginError, remove_account

    import logging
    logging.getLogger("slixmpp").setLevel(logging.CRITICAL)  # a failed login is reported as one line
    settings = XmppSettings.from_env()
    name, password = account or (f"cli-{uuid.uuid4().hex[:8]}", generate_password())
    client = RappAgent(name, settings, password=password)
    await client.start()
    try:
        return await fn(client, settings)
    finally:
        await client.stop()
        if account is None:
            try:
                await remove_account(settings.host, settings.port, settings.domain, user=name, password=password)
            except LoginError:
                pass


def cmd_store(a) -> int:
    from ontology import store as S

    async def run(client, settings):
        store = settings.jid(a.store)
        if a.action == "publish":
            from agents.store_client import publish_package
            if not (a.owner and a.password):
                raise CliError("publish needs --owner and --password")
            await client.request(store, S.RegisterOwner(owner=a.owner, password=a.password))
            d = await publish_package(client, store, a.owner, a.password, Path(a.target).read_bytes())
            print(f"published {d.summary.name} {d.summary.version} ({d.summary.size} bytes)")
            builds = d.builds if a.no_wait else await _wait_for_builds(client, store, d, a.build_timeout)
            for b in builds:
                print(f"  {b.robot_type:10} {b.state:9} {b.reason}".rstrip())
            if any(b.state == S.BuildState.FAILED for b in builds):
                print(f"  logs: rapp store log {d.summary.name} --version {d.summary.version} --robot-type TYPE")
        elif a.action == "list":
            reply = await client.request(store, S.ListPackages(robot_type=a.robot_type))
            for p in reply.packages:
                print(f"{p.name:24} {p.version:10} {','.join(p.robot_types):16} {' '.join(p.keywords)}")
        elif a.action == "info":
            d = await client.request(store, S.Info(name=a.target))
            print(f"{d.summary.name} {d.summary.version} by {d.owner}; versions {', '.join(d.versions)}")
            print(f"  {d.summary.description}")
            print(f"  robots: {', '.join(d.summary.robot_types)}; keywords: {', '.join(d.summary.keywords)}")
            print(f"  sha256 {d.summary.sha256}; signed by {d.signer_key_id or 'nobody'}")
        elif a.action == "builds":
            reply = await client.request(store, S.Builds(name=a.target, version=a.version))
            for b in reply.builds:
                print(f"{b.name:24} {b.version:10} {b.robot_type:10} {b.state:9} {b.reason}".rstrip())
        elif a.action == "log":
            if not a.robot_type:
                raise CliError("store log needs --robot-type")
            version = a.version or (await client.request(store, S.Info(name=a.target))).summary.version
            reply = await client.request(store, S.BuildLog(name=a.target, version=version, robot_type=a.robot_type))
            print(reply.log, end="" if reply.log.endswith("\n") else "\n")
        elif a.action == "serve":
            from scenarios.store_page import serve_forever
            await serve_forever(client, store, host=a.host, port=a.port)
        elif a.action == "remove":
            d = await client.request(store, S.Delete(owner=a.owner, password=a.password, name=a.target,
                                                     version=a.version))
            print(f"removed {d.name} {', '.join(d.versions)}")
        return 0

    if a.action in ("publish", "info", "remove", "log") and not a.target:
        raise CliError(f"store {a.action} needs a target")
    if a.action in ("publish", "remove"):  # owner operations come from the owner's own XMPP account
        if not (a.owner and a.password):
            raise CliError(f"store {a.action} needs --owner and --password")
        from agents.errors import AgentStartError
        try:
            return asyncio.run(_with_client(run, account=(a.owner, a.password)))
        except AgentStartError as e:
            raise CliError(f"the XMPP server refused owner {a.owner!r} (wrong password?): {e}") from None
    return asyncio.run(_with_client(run))


async def _wait_for_builds(client, store: str, details, timeout_s: float) -> list:
    """The version's builds once none is queued or running (or as they are after `timeout_s`),
    with a line on stderr whenever one ends."""
    import time

    from ontology import store as S

    deadline, told = time.monotonic() + timeout_s, set()
    while True:
        reply = await client.request(store, S.Builds(name=details.summary.name, version=details.summary.version))
        for b in reply.builds:
            if b.state not in (S.BuildState.QUEUED, S.BuildState.BUILDING) and b.robot_type not in told:
                told.add(b.robot_type)
                print(f"  built for {b.robot_type}: {b.state}", file=sys.stderr, flush=True)
        if all(b.state not in (S.BuildState.QUEUED, S.BuildState.BUILDING) for b in reply.builds) \
                or time.monotonic() > deadline:
            return reply.builds
        await asyncio.sleep(1.0)


# -- house ------------------------------------------------------------------------------------
def cmd_house(a) -> int:
    from scenarios import house_check
    if a.action == "new":
        path = house_check.new_file(a.target, a.output)
        print(f"wrote {path}: check and draw it with `rapp house check {path}` (docs/houses.md)")
        return 0
    plan, problems = house_check.check_file(a.target, seed=a.seed)
    png = house_check.draw(plan, a.output or f"{Path(a.target).stem}.png")
    print(house_check.summary(plan))
    for p in problems:
        print(f"  problem: {p}")
    print(f"{a.target}: {'valid' if not problems else f'{len(problems)} problem' + 's' * (len(problems) > 1)}; drawn at seed {a.seed} in {png}")
    return 1 if problems else 0


# -- platform ---------------------------------------------------------------------------------
def cmd_platform(a) -> int:
    """What a robot owner uploads once: the home description and map of a house, as their own
    user (logged in with their Platform password)."""
    from ontology import platform as P

    if not (a.user and a.password):
        raise CliError("upload-home needs --user and --password (the owner's Platform login)")

    async def run(client, settings):
        from robots import World
        from scenarios.home_setup import HOUSES, has_layout, home_description, upload_home_over_xmpp

        try:
            world = World.from_file(a.house, seed=a.seed)
        except (OSError, ValueError, KeyError) as e:
            raise CliError(f"no house {a.house!r} (known: {', '.join(HOUSES)}, or a YAML file): {e}") from None
        if not has_layout(a.house, world):
            world.close()
            raise CliError(f"no home description for house {a.house!r} (known: {', '.join(HOUSES)})")
        platform = settings.jid(a.platform)
        login = await client.request(platform, P.Login(user=a.user, password=a.password, ttl_s=600))
        import tempfile

        try:
            with tempfile.TemporaryDirectory(prefix="rapp-home-") as tmp:
                info, png, yaml_text = home_description(world, a.house, Path(tmp))
        finally:
            world.close()
        await upload_home_over_xmpp(client, platform, login.token, info, png, yaml_text)
        print(f"uploaded home {info.home_id!r} (map {info.map_id}, {len(info.hazards)} hazards, "
              f"{len(info.landmarks)} landmarks) for {a.user}")
        return 0

    return asyncio.run(_with_client(run))


# -- trace ------------------------------------------------------------------------------------
def cmd_trace(argv: list[str]) -> int:
    actions = {"show", "export", "html"}
    action = argv[0] if argv and argv[0] in actions else "show"
    if argv and argv[0] in actions:
        argv = argv[1:]
    from scenarios import trace_report as tr

    what = {"show": "a run's trace: a summary (agents by role, messages, structure changes, task ends, "
                    "problems), or its messages as a table or a sequence diagram",
            "export": "a run's trace as a Mermaid sequence diagram, JSON or text",
            "html": "a run's trace as one self-contained HTML page"}[action]
    p = argparse.ArgumentParser(prog=f"rapp trace {action}", description=f"{what} (rapp trace show|export|html FILE)")
    p.add_argument("file", help="a trace.jsonl, or the run folder that holds one (every `rapp run` writes one in "
                                "its --out folder)")
    p.add_argument("--agent", action="append", help="only records of this agent (repeatable): a role ("
                   f"{', '.join(tr.ROLES)}), a name (core-nao1) or a JID")
    p.add_argument("--conversation", action="append", help="only this conversation id (prefix ok)")
    if action == "show":
        p.add_argument("--view", choices=["summary", "table", "sequence", "both", "fsm"], default="summary",
                       help="summary (default), the messages as a table, as a sequence diagram, or both; fsm: "
                            "each agent's FSM path and its request passes (fig. 5's s9, fig. 6)")
        p.add_argument("--limit", type=int, default=200, metavar="N",
                       help="table and sequence: the first N messages and records (default 200; 0: all)")
    if action == "export":
        p.add_argument("--format", choices=["mermaid", "json", "text", "states", "mcap"], default="mermaid",
                       help="mermaid: a sequence diagram; states: each agent's FSM as a Mermaid state diagram; "
                            "mcap: the whole run folder (FILE: the folder or its trace.jsonl) as an MCAP file for "
                            "Foxglove or Lichtblick (docs/recordings.md; default output RUN_DIR/run.mcap)")
        p.add_argument("--no-frames", action="store_true", help="mcap: without the camera's frames")
    if action in ("export", "html"):
        p.add_argument("-o", "--output", help="output file (default: stdout for export, FILE.html for html)")
    if action == "html":
        p.add_argument("--no-scene", action="store_true", help="without the map, poses and camera frames of a "
                                                               "recorded run (robot.jsonl beside the trace)")
    a = p.parse_args(argv)
    from agents.tracing import read_trace

    if action == "export" and a.format == "mcap":
        return _export_mcap(Path(a.file), a.output, frames=not a.no_frames)
    if Path(a.file).is_dir():  # a run's folder: its trace
        if not (Path(a.file) / "trace.jsonl").is_file():
            raise CliError(f"{a.file} is a folder without a trace.jsonl (a `rapp run --out` folder has one)")
        a.file = str(Path(a.file) / "trace.jsonl")
    if not Path(a.file).exists():
        raise CliError(f"no trace file {a.file}")
    records = tr.filter_records(read_trace(a.file), agents=a.agent, conversations=a.conversation)
    if action == "show":
        if a.view == "summary":
            print(tr.summary_text(records, Path(a.file).name))
            return 0
        if a.view == "fsm":
            from scenarios.fsm_view import fsm_text
            print(fsm_text(records))
            return 0
        shown, more = tr.limit_items(records, a.limit)
        if a.view in ("table", "both"):
            print(tr.table(shown))
        if a.view in ("sequence", "both"):
            print(tr.sequence_text(shown))
        if more:
            print(f"... {more} more records (--limit N, or --limit 0 for all)")
        return 0
    if action == "export":
        import json
        from scenarios.fsm_view import fsm_mermaid
        text = {"mermaid": lambda: tr.mermaid(records), "text": lambda: tr.sequence_text(records),
                "states": lambda: fsm_mermaid(records),
                "json": lambda: json.dumps(records, indent=1)}[a.format]()
        if a.output:
            Path(a.output).write_text(text)
        else:
            print(text)
        return 0
    from scenarios.trace_html import render_html, scene_data
    out = Path(a.output or (str(a.file) + ".html"))
    scene = None if a.no_scene else scene_data(Path(a.file).parent)  # a recorded run's map, poses and frames
    out.write_text(render_html(records, title=Path(a.file).name, scene=scene))
    print(out)
    return 0


def _export_mcap(src: Path, output: str | None, frames: bool) -> int:
    from scenarios.mcap_export import export_mcap

    run = src if src.is_dir() else src.parent
    if not (run / "trace.jsonl").exists():
        raise CliError(f"no run folder {src} (a folder with trace.jsonl, as `rapp run ... --out DIR` writes)")
    out = export_mcap(run, output or run / "run.mcap", frames=frames)
    print(f"{out} ({out.stat().st_size} bytes)")
    return 0


# -- replay -----------------------------------------------------------------------------------
def cmd_replay(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="rapp replay", description=(
        "Run a recorded run's RApp again as a Dynamic Agent against the recorded answers of its Core, Platform "
        "and Cloud Agent (no simulation, no Store; an embedded XMPP server of its own) and print the first "
        "divergence, or 'no divergence' (docs/recordings.md). Exit 0: no divergence; 1: a divergence."))
    p.add_argument("run_dir", help="a recorded run folder (every `rapp run` writes one with --out)")
    p.add_argument("--rapp", metavar="DIR", help="replay this (changed) RApp source folder instead of the recorded "
                                                  "package: how a refactor is checked without a robot")
    p.add_argument("--run", type=int, metavar="N", help="which RApp run of the recording (1-based; default the last)")
    p.add_argument("--list", action="store_true", help="list the recording's RApp runs and exit")
    p.add_argument("--save", metavar="DEST", help="copy what a replay needs (trace, message bodies, packages, "
                                                  "result; no credentials) to DEST, e.g. a RApp's tests/recording, "
                                                  "and exit (docs/sdk.md 'A recording as a test')")
    p.add_argument("--in-process", action="store_true", help="run the RApp in this process, unsandboxed (faster; "
                                                              "your own code only)")
    p.add_argument("--stall", type=float, default=10.0, metavar="S",
                   help="seconds, beyond twice the recorded time, the RApp may take to send the request the "
                        "recording has next before the replay says it stalled (default 10)")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds the whole replay may take (default 600)")
    p.add_argument("--trace", metavar="FILE", help="write the replay's own trace there")
    a = p.parse_args(argv)
    from rapps.replay import RecordingError, list_runs, replay, save_recording

    try:
        if a.save:
            copied = save_recording(a.run_dir, a.save)
            print(f"saved in {a.save}: {', '.join(copied)}")
            return 0
        if a.list:
            print("\n".join(list_runs(a.run_dir)) or "no RApp runs in this recording")
            return 0
        if a.rapp and not Path(a.rapp).is_dir():
            raise CliError(f"no RApp folder {a.rapp}")
        result = asyncio.run(replay(a.run_dir, rapp_dir=a.rapp, run=a.run, mode="inprocess" if a.in_process else "process",
                                    stall_s=a.stall, timeout_s=a.timeout, trace_file=a.trace))
    except RecordingError as e:
        raise CliError(f"rapp replay: {e}") from None
    print(result.summary())
    return 0 if result.ok else 1


# -- say --------------------------------------------------------------------------------------
def cmd_say(a) -> int:
    from pydantic import ValidationError

    from scenarios.owner_voice import ScriptError, SpokenLine, post_line
    try:
        line = SpokenLine(say=a.text, voice=a.voice, speed=a.speed, distance=a.distance, level_db=a.level)
        _check_voice(line.voice)
        path = post_line(line, a.run)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise CliError(f"rapp say: {'.'.join(map(str, first['loc']))}: {first['msg']}") from None
    except ScriptError as exc:
        raise CliError(f"rapp say: {exc}") from None
    print(f"said into {path.parent.parent}: {a.text!r}")
    return 0


def _check_voice(voice: str) -> None:
    """An unknown voice is refused here, not only in the run's own output (where the line is dropped)."""
    from hearing import tts
    from hearing.errors import InvalidArgument, SpeechUnavailable
    try:
        tts.check_voice(voice)
    except InvalidArgument as e:
        raise CliError(f"rapp say: {e}") from None
    except SpeechUnavailable:
        pass  # no eSpeak NG here: the run says whether it can speak


# -- doctor -----------------------------------------------------------------------------------
def cmd_doctor(a) -> int:
    from scenarios.doctor import run_checks
    return run_checks()


def build_parser() -> argparse.ArgumentParser:
    from ontology import robot_types  # the --robot choices (imported here: `rapp --help` stays quick)

    p = argparse.ArgumentParser(prog="rapp", description="RAPP variable-structure robot control system")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("server", help="run the embedded XMPP server (pyjabber) on this machine",
                       description="Run the embedded XMPP server (pyjabber) until Ctrl-C, for agents started with "
                                   "`rapp agent` (a `rapp run` starts its own).")
    s.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    s.add_argument("--port", type=int, default=5222, help="client port (default 5222)")
    s.add_argument("--domain", default="localhost", help="the XMPP domain of the agents' JIDs (default localhost)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--db", help="SQLite file for accounts (default: a fresh file per run)")
    g.add_argument("--memory", action="store_true", help="in-memory database (pyjabber loses it on some disconnects)")
    s.add_argument("--verbose", action="store_true", help="log the server's connections and stanzas")

    r = sub.add_parser("run", help=f"run a scenario ({', '.join(SCENARIOS)})", epilog=_scenario_list(),
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Run a scenario on simulated robots with its own XMPP server, Store and Platform.")
    r.add_argument("scenario", choices=list(SCENARIOS), metavar="SCENARIO", help="one of the scenarios below")

    t = sub.add_parser("test", help="run a RApp's tests (with what `pip install -e .` installs)",
                       description="Run the tests of a RApp folder (its tests/ folder, else the folder) with pytest, "
                                   "as `pip install -e .` installed it: async tests need no mark, the checkout's "
                                   "pytest configuration is not used. Options after DIR go to pytest (-k, -x, -q).")
    t.add_argument("dir", help="the RApp's folder (as `rapp new` made it)")
    t.add_argument("--robot", choices=robot_types.names(), help="the robot type its tests run for (RAPP_ROBOT_TYPE), "
                                                                 "as the Store's build runs them once per type")

    n = sub.add_parser("new", help="create a RApp package to start from (manifest, task, test)",
                       description="Create a RApp folder to start from: a manifest, a task with a two-state FSM, "
                                   "a test (and with --cloud a Cloud Agent part); docs/sdk.md walks through one.")
    n.add_argument("name", help="the RApp's name (lower case, dashes)")
    n.add_argument("dir", nargs="?", help="where to create it (default: ./NAME)")
    n.add_argument("--cloud", action="store_true", help="with a Cloud Agent part")

    k = sub.add_parser("package", help="build a RApp package or a signing key; print the manifest's JSON Schema",
                       description="build: a .rapp package of a RApp folder (signed with --key); keygen: an ed25519 "
                                   "signing key; schema: the manifest's JSON Schema.")
    k.add_argument("action", choices=["build", "keygen", "schema"], help="what to do")
    k.add_argument("dir", nargs="?", help="RApp source directory (build), key file to write (keygen), "
                                          "schema file to write (schema; default: stdout)")
    k.add_argument("-o", "--output", help="build: the package file or a folder for it (default: the current "
                                          "folder); schema: the file to write")
    k.add_argument("--key", help="ed25519 private key (PEM) to sign with")

    st = sub.add_parser("store", help="talk to the Store Agent on the configured XMPP server",
                        description="Publish, list, describe or remove RApp packages in the Store Agent on the "
                                    "configured XMPP server (RAPP_XMPP_*; docs/deployment.md).")
    st.add_argument("action", choices=["publish", "list", "info", "remove", "builds", "log", "serve"],
                    help="what to do (builds: each version's build per robot type; log: one build's log; serve: "
                         "a page for developers listing packages, versions, builds and logs)")
    st.add_argument("target", nargs="?", help="package file (publish) or package name")
    st.add_argument("--owner", help="publish, remove: the Store owner's name (their own XMPP account)")
    st.add_argument("--password", help="publish, remove: the owner's password")
    st.add_argument("--version", help="remove: only this version (default: every version); builds, log: this version")
    st.add_argument("--robot-type", choices=robot_types.names(),
                    help="list: only packages for this robot type; log: the build's robot type")
    st.add_argument("--no-wait", action="store_true", help="publish: do not wait for the builds")
    st.add_argument("--build-timeout", type=float, default=1800.0, metavar="S",
                    help="publish: seconds to wait for the builds (default 1800)")
    st.add_argument("--host", default="127.0.0.1", help="serve: address (default 127.0.0.1: this machine only)")
    st.add_argument("--port", type=int, default=8780, help="serve: port (default 8780; 0: any free one)")
    st.add_argument("--store", default="store", help="the Store Agent's name or JID")

    pl = sub.add_parser("platform", help="talk to the Platform Agent as a robot owner",
                        description="upload-home: the home description and map of a house, as the robot owner "
                                    "uploads them once before asking for hazard checks.")
    pl.add_argument("action", choices=["upload-home"], help="what to do")
    pl.add_argument("--house", default="small", help="house whose home description and map to upload "
                                                      "(small, house, or generated with --seed)")
    pl.add_argument("--seed", type=int, default=0, help="the generated house's seed")
    pl.add_argument("--user", help="the owner's Platform user name")
    pl.add_argument("--password", help="the owner's Platform password")
    pl.add_argument("--platform", default="platform", help="the Platform Agent's name or JID")

    ho = sub.add_parser("house", help="check and draw a house file, or start one (docs/houses.md)",
                        description="check FILE: validate a house file (its keys and types against "
                                    "docs/house.schema.json, doors and landmarks on walls, ids that exist, "
                                    "robots that fit, doors' check poses clear of furniture) and draw it as a PNG; "
                                    "exit code 1 when it has problems. new NAME: write a house file to start "
                                    "from (a valid two-room flat).")
    ho.add_argument("action", choices=["check", "new"], help="what to do")
    ho.add_argument("target", help="check: the house file (YAML); new: the house's name")
    ho.add_argument("-o", "--output", help="check: the PNG to write (default: ./FILE_STEM.png); "
                                           "new: the file or folder to write (default: ./NAME.yaml)")
    ho.add_argument("--seed", type=int, default=0, help="check: the seed drawing random door angles, lamps "
                                                        "and robot starts (default 0)")

    sy = sub.add_parser("say", help="the owner speaks into a running `rapp run` (the robot hears it)",
                        description="The owner says TEXT aloud in the house of a running `rapp run` (started with "
                                    "--listen or --speak): the robot hears it through its microphone.")
    sy.add_argument("text", help="what the owner says")
    sy.add_argument("--run", help="the run's --out folder (default: the newest running `rapp run`)")
    sy.add_argument("--distance", type=float, default=1.0, help="metres from the robot (0.3-8)")
    sy.add_argument("--voice", default="en-us", help="eSpeak NG voice (en-us, en, en-gb-x-rp, ...)")
    sy.add_argument("--speed", type=int, default=150, help="words per minute (80-450)")
    sy.add_argument("--level", type=float, default=60.0, help="dB SPL at 1 m (60: conversation)")

    sub.add_parser("trace", help="show, export or render a message trace (rapp trace FILE)", add_help=False)
    sub.add_parser("replay", help="replay a recorded RApp run against its recorded answers (rapp replay --help)",
                   add_help=False)
    sub.add_parser("bench", help="run the benchmarks (rapp bench --help)", add_help=False)
    sub.add_parser("agent", help="run one Store, Platform or Core agent here (rapp agent --help)",
                   add_help=False)
    sub.add_parser("doctor", help="check the installation and the configured XMPP server",
                   description="Check the pinned versions, PyBullet, OpenCV, speech and the configured XMPP server, "
                               "one line each.")
    return p


def main(argv: list[str] | None = None) -> int:
    if argv is None and next((a for a in sys.argv[1:] if not a.startswith("-")), "") != "server":
        # the program (not a caller's main([...])): only `rapp server` runs pyjabber in this process
        from xmpp_server.compat import spade_without_its_server
        spade_without_its_server()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:  # a native crash in a library prints every thread's Python stack to stderr
        faulthandler.enable()
    except (OSError, ValueError, AttributeError):  # stderr is no file (captured, embedded): no stacks then
        pass
    debug = "--debug" in argv
    if debug:
        argv.remove("--debug")
    try:
        if argv and argv[0] == "trace":
            return cmd_trace(argv[1:])
        if argv and argv[0] == "replay":
            return cmd_replay(argv[1:])
        if argv and argv[0] == "agent":
            from scenarios.roles import main as agent_main
            return agent_main(argv[1:])
        if argv[:1] == ["run"] and len(argv) > 1 and not argv[1].startswith("-"):
            # the scenario parses the rest itself (so `rapp run SCENARIO --help` is its own help)
            return cmd_run(argparse.Namespace(scenario=argv[1]), argv[2:])
        if argv and argv[0] == "bench":
            from bench.runner import main as bench_main
            return bench_main(argv[1:], prog="rapp bench")
        parser = build_parser()
        a, rest = parser.parse_known_args(argv)
        if a.command == "run":
            return cmd_run(a, rest)
        if a.command == "test":
            return cmd_test(a, rest)
        if rest:
            parser.error(f"unrecognized arguments: {' '.join(rest)}")
        return {"server": cmd_server, "package": cmd_package, "store": cmd_store,
                "platform": cmd_platform, "house": cmd_house, "new": cmd_new, "doctor": cmd_doctor, "say": cmd_say}[a.command](a)
    except KeyboardInterrupt:
        return 130
    except SystemExit:
        raise
    except Exception as e:  # noqa: BLE001 - one clear line for users; --debug for the traceback
        if debug:
            raise
        print(f"rapp: error: {_one_line(e)}", file=sys.stderr)
        return 1
    except BaseException as e:  # scenarios.runner.RunInterrupted (its run's files are written): not a crash
        if type(e).__name__ != "RunInterrupted":
            raise
        print(f"rapp: {e}", file=sys.stderr)
        return 128 + e.signum


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0] if text else ''}".rstrip(": ") if not isinstance(e, CliError) else text[0]


if __name__ == "__main__":
    sys.exit(main())
