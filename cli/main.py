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
    rapp platform upload-home --house H --user U --password P
    rapp house check FILE [-o PNG] [--seed N] | rapp house new NAME [-o FILE]   (house files: docs/houses.md)
    rapp trace show|export|html FILE [...]      (rapp trace FILE = show: a summary; --view, --limit)
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
    without marks, nothing cached into the RApp's folder."""
    import os

    import pytest

    target = Path(a.dir)
    if not target.exists():
        raise CliError(f"no RApp folder {target}")
    tests = target / "tests" if (target / "tests").is_dir() else target
    args = [str(tests), "--rootdir", str(target if target.is_dir() else target.parent), "-c", os.devnull,
            "-p", "no:cacheprovider", "-o", "asyncio_mode=auto", "-o", "asyncio_default_fixture_loop_scope=function",
            "-o", "asyncio_default_test_loop_scope=function", *rest]
    return int(pytest.main(args))


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
        elif a.action == "remove":
            d = await client.request(store, S.Delete(owner=a.owner, password=a.password, name=a.target,
                                                     version=a.version))
            print(f"removed {d.name} {', '.join(d.versions)}")
        return 0

    if a.action in ("publish", "info", "remove") and not a.target:
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
    p.add_argument("file", help="a trace.jsonl (every `rapp run` writes one in its --out folder)")
    p.add_argument("--agent", action="append", help="only records of this agent (repeatable): a role ("
                   f"{', '.join(tr.ROLES)}), a name (core-nao1) or a JID")
    p.add_argument("--conversation", action="append", help="only this conversation id (prefix ok)")
    if action == "show":
        p.add_argument("--view", choices=["summary", "table", "sequence", "both"], default="summary",
                       help="summary (default), the messages as a table, as a sequence diagram, or both")
        p.add_argument("--limit", type=int, default=200, metavar="N",
                       help="table and sequence: the first N messages and records (default 200; 0: all)")
    if action == "export":
        p.add_argument("--format", choices=["mermaid", "json", "text"], default="mermaid")
    if action in ("export", "html"):
        p.add_argument("-o", "--output", help="output file (default: stdout for export, FILE.html for html)")
    a = p.parse_args(argv)
    from agents.tracing import read_trace

    if not Path(a.file).exists():
        raise CliError(f"no trace file {a.file}")
    records = tr.filter_records(read_trace(a.file), agents=a.agent, conversations=a.conversation)
    if action == "show":
        if a.view == "summary":
            print(tr.summary_text(records, Path(a.file).name))
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
        text = {"mermaid": lambda: tr.mermaid(records), "text": lambda: tr.sequence_text(records),
                "json": lambda: json.dumps(records, indent=1)}[a.format]()
        if a.output:
            Path(a.output).write_text(text)
        else:
            print(text)
        return 0
    from scenarios.trace_html import render_html
    out = Path(a.output or (str(a.file) + ".html"))
    out.write_text(render_html(records, title=Path(a.file).name))
    print(out)
    return 0


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
    st.add_argument("action", choices=["publish", "list", "info", "remove"], help="what to do")
    st.add_argument("target", nargs="?", help="package file (publish) or package name")
    st.add_argument("--owner", help="publish, remove: the Store owner's name (their own XMPP account)")
    st.add_argument("--password", help="publish, remove: the owner's password")
    st.add_argument("--version", help="remove: only this version (default: every version)")
    st.add_argument("--robot-type", help="list: only packages for this robot type")
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
    sub.add_parser("bench", help="run the benchmarks (rapp bench --help)", add_help=False)
    sub.add_parser("agent", help="run one Store, Platform or Core agent here (rapp agent --help)",
                   add_help=False)
    sub.add_parser("doctor", help="check the installation and the configured XMPP server",
                   description="Check the pinned versions, PyBullet, OpenCV, speech and the configured XMPP server, "
                               "one line each.")
    return p


def main(argv: list[str] | None = None) -> int:
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
        if argv and argv[0] == "agent":
            from scenarios.roles import main as agent_main
            return agent_main(argv[1:])
        if argv[:1] == ["run"] and len(argv) > 1 and not argv[1].startswith("-"):
            # the scenario parses the rest itself (so `rapp run SCENARIO --help` is its own help)
            return cmd_run(argparse.Namespace(scenario=argv[1]), argv[2:])
        if argv and argv[0] == "bench":
            from bench.runner import main as bench_main
            return bench_main(argv[1:])
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
