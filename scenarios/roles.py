"""`rapp agent ROLE`: run one kind of agent on this machine against the configured XMPP server
(XmppSettings from RAPP_XMPP_*), until Ctrl-C. This is how a deployment spreads the system over
machines: Store and Platform on a server, one Core per robot (docs/deployment.md).

    rapp agent store --data /var/lib/rapp/store
    rapp agent platform --data /var/lib/rapp/platform --maps /var/lib/rapp/maps --replica platform-2
    rapp agent platform --name platform-2 --primary platform      # a replica: adds capacity
    rapp agent core --robot nao --robot-id nao1 --owner alice --trust dev.pub --house house --seed 1
    rapp agent core ... --record runs/alice-1      # and a recording of it (docs/recordings.md)

Each agent logs in with its own password (RAPP_XMPP_PASSWORD, or its file in the credentials
directory, generated on first start: xmpp_server/credentials.py). Data directories default to
~/.local/share/rapp/<role> (XDG_DATA_HOME).
"""
from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import signal
import sys
from pathlib import Path

from ontology import robot_types
from xmpp_server.settings import XmppSettings


async def _run_until_stopped(agents, cleanup=None, after_start=None) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    for a in agents:
        await a.start()
        print(f"{a.address} running ({type(a).__name__}); Ctrl-C stops it", flush=True)
    extra = asyncio.create_task(after_start()) if after_start else None
    await stop.wait()
    if extra is not None:
        extra.cancel()
    for a in agents:
        with contextlib.suppress(Exception):
            await a.stop()
    if cleanup:
        cleanup()


def data_dir(role: str, given: str | None) -> Path:
    if given:
        return Path(given)
    base = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return base / "rapp" / role


async def _store(a, settings) -> None:
    from agents.store_agent import StoreAgent
    await _run_until_stopped([StoreAgent(a.name or "store", data_dir("store", a.data), settings,
                                         require_signature=a.require_signature, platform=a.platform,
                                         build=not a.no_build, require_tests=a.require_tests)])


async def _platform(a, settings) -> None:
    from agents.platform_agent import PlatformAgent
    from agents.services.context import ServiceState
    from scenarios.system import CLOUD_WARM_IMPORTS

    # a second Platform on the same machine (a replica) must not share the first one's files
    home = data_dir(a.name or "platform", a.data)
    # every per-user datum (maps, homes, learned objects, faces and scenes, history, marks: SQLite and
    # blob files, agents/services/saved.py) and per-user files (maildirs) survive a restart
    state = ServiceState.keeping(home)
    if a.maps:
        print(f"maps preloaded: {', '.join(state.preload_maps(a.maps)) or 'none'}")
    platform = PlatformAgent(a.name or "platform", store=a.store, settings=settings, services_state=state,
                             data_dir=home, workdir=a.workdir or home / "work", sandbox=sandbox(a),
                             primary=a.primary, replicas=a.replica, service_workers=a.service_workers,
                             warm_imports=CLOUD_WARM_IMPORTS,
                             **({"warm_workers": a.warm_workers, "warm_hold_running": True}
                                if a.warm_workers is not None else {}))
    async def fill_pool() -> None:  # asked for: filled from the start, not at the first Cloud Agent
        if a.warm_workers:
            platform.start_cloud_workers()
            try:
                await platform.warm_pool.wait_ready(timeout=60.0 + 10.0 * a.warm_workers)
                print(f"cloud workers ready: {a.warm_workers}", flush=True)
            except asyncio.TimeoutError:
                print(f"cloud workers not all ready: {len(platform.warm_pool.idle)} of {a.warm_workers}", flush=True)

    await _run_until_stopped([platform], after_start=fill_pool)


def owner_password(a, settings) -> str:
    """The owner's Platform/Store password: given, or generated once and kept (0600) in the
    credentials directory; never a default anyone could guess."""
    from xmpp_server.credentials import CredentialStore

    if a.password:
        return a.password
    store = CredentialStore(settings.credentials_dir)
    path = store.path(f"owner-{a.owner}")
    existed = path.exists()
    password = store.password(f"owner-{a.owner}")
    if not existed:
        print(f"generated a password for owner {a.owner!r}: it is in {path} (give it with --password "
              f"to use your own)", flush=True)
    return password


def trust(a) -> dict:
    """CoreOptions fields for package signatures: keys the owner trusts, or (loudly)
    none for development."""
    from ontology.package import load_public_key

    if a.allow_unsigned:
        print("WARNING: --allow-unsigned: this Core runs RApps nobody signed, from any Store owner",
              file=sys.stderr, flush=True)
        return {"trusted_keys": None, "require_signature": False}
    if not a.trust:
        raise SystemExit("rapp agent core: give --trust KEY (a public key file or base64 key of a "
                         "signer you trust; repeatable) or, for development only, --allow-unsigned")
    keys = [load_public_key(Path(k).read_bytes() if Path(k).exists() else k) for k in a.trust]
    return {"trusted_keys": keys, "require_signature": True}


def sandbox(a):
    from agents.sandbox import Sandbox, allow_unsandboxed, describe

    if not allow_unsandboxed(a.allow_unsandboxed, f"rapp agent {a.role}"):
        raise SystemExit(2)
    box = Sandbox()
    print(describe(), file=sys.stderr, flush=True)  # what this machine gives RApps, and what it lacks
    return box


async def _core(a, settings) -> None:
    from agents.core_agent import CoreAgent, CoreOptions
    from robots import RobotAPI, World
    from scenarios.system import DYNAMIC_WARM_IMPORTS

    world = World.from_file(a.house, seed=a.seed, rtf=a.rtf)
    api = RobotAPI(world.add_robot(a.robot))
    robot_id = a.robot_id or f"{a.robot}1"
    recording = None
    if a.record:  # this Core's recording (docs/recordings.md): its trace, message bodies, robot, run.mcap
        from scenarios.recorder import RecordingAPI
        from scenarios.recording import Recording
        from scenarios.runner import plot_grid

        out = Path(a.record)
        out.mkdir(parents=True, exist_ok=True)
        settings = settings.model_copy(update={"trace_file": out / "trace.jsonl"})
        api = RecordingAPI(api)
        recording = Recording(out, world, {a.robot: api}, plot_grid(world, a.house))
        recording.begin()
        print(f"recording into {out} (run.mcap written when it stops)", flush=True)
    core = CoreAgent(a.name or f"core-{robot_id}", robot_id=robot_id, robot_type=a.robot, robot_api=api,
                     owner=a.owner, platform=a.platform, store=a.store, user=a.owner,
                     password=owner_password(a, settings), settings=settings,
                     options=CoreOptions(sandbox=sandbox(a), workdir=a.workdir or data_dir(f"core-{robot_id}", a.data) / "work",
                                         data_dir=data_dir(f"core-{robot_id}", a.data),  # its schedules (agents/scheduler.py)
                                         warm_imports=DYNAMIC_WARM_IMPORTS, **trust(a)))

    async def home() -> None:  # the owner's home description, for RApps that need one
        from scenarios.home_setup import ensure_home

        while not core.token:
            await asyncio.sleep(0.2)
        try:
            print(await ensure_home(core, world, a.house, core.workdir.parent / "home"), flush=True)
        except Exception as e:  # noqa: BLE001 - the Core serves on without a home
            print(f"home description not uploaded: {type(e).__name__}: {e}", file=sys.stderr, flush=True)

    async def record_and_home() -> None:
        if recording is not None:
            recording.start()
        await home()

    try:
        await _run_until_stopped([core], after_start=record_and_home)
        if recording is not None:
            print(f"recorded: {await recording.finish()}", flush=True)
    finally:
        world.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="rapp agent", description=__doc__.split("\n\n")[0])
    p.add_argument("role", choices=["store", "platform", "core"], help="the agent to run here")
    p.add_argument("--name", help="the agent's account name (default: store / platform / core-ROBOT_ID)")
    p.add_argument("--store", default="store", help="the Store Agent's name or JID")
    p.add_argument("--platform", default="platform", help="the Platform Agent's name or JID")
    p.add_argument("--data", help="store, platform, core: data directory (default ~/.local/share/rapp/ROLE; a "
                                   "Core's: its schedules)")
    p.add_argument("--require-signature", action="store_true", help="store: refuse unsigned packages")
    p.add_argument("--no-build", action="store_true", help="store: run no package's tests; list every declared "
                                                           "robot type untested (development only)")
    p.add_argument("--require-tests", action="store_true", help="store: refuse packages without tests")
    p.add_argument("--workdir", help="core, platform: where RApp runs unpack and log (default: "
                                      "~/.local/share/rapp/<agent>/work; emptied at every stop and start)")
    p.add_argument("--maps", help="platform: directory of map_server YAML maps to preload")
    p.add_argument("--primary", help="platform: run as a replica of this primary Platform (name or JID): "
                                      "it serves the stateless services and reports its load there")
    p.add_argument("--replica", action="append", default=[], metavar="NAME",
                   help="platform: a replica this primary trusts (name or JID); repeatable")
    p.add_argument("--service-workers", type=int, default=None, metavar="N",
                   help="platform: processes for the CPU-bound services (default: one per core; 0: threads)")
    p.add_argument("--warm-workers", type=int, default=None, metavar="N",
                   help="platform: Cloud Agent processes kept started ahead of time (default: 1, from the "
                        "first Cloud Agent on; N: filled at start, for N robots starting Cloud Agents at once, "
                        "and never more than N Cloud Agent processes, idle or running: a worker handed a run "
                        "is replaced when that run ends)")
    p.add_argument("--robot", choices=robot_types.names(), default="nao", help="core: robot type")
    p.add_argument("--robot-id", help="core: the robot's id (default: the type and 1, e.g. nao1)")
    p.add_argument("--owner", default="owner", help="core: the user whose chat it listens to")
    p.add_argument("--password", help="core: the owner's Platform/Store password (default: generated "
                                       "once, kept in the credentials directory)")
    p.add_argument("--trust", action="append", default=[], metavar="KEY",
                   help="core: public key (file or base64) of a RApp signer the owner trusts; repeatable")
    p.add_argument("--allow-unsigned", action="store_true",
                   help="core: DEVELOPMENT ONLY: run unsigned RApps from any Store owner")
    p.add_argument("--allow-unsandboxed", action="store_true",
                   help="core, platform: DEVELOPMENT ONLY: run RApps (Cloud Agents) without the "
                        "sandbox where the kernel allows none (no user namespaces; the reason is printed)")
    p.add_argument("--house", default="small", help="core: simulated house (name or YAML file)")
    p.add_argument("--seed", type=int, default=0, help="core: draws the simulated house's world (door angles, lamps)")
    p.add_argument("--rtf", type=float, default=1.0, help="core: simulation real-time factor")
    p.add_argument("--record", metavar="DIR", help="core: record into DIR (trace, whole message bodies with secrets "
                   "as placeholders, the RApp packages, the robot's poses and frames; run.mcap at stop; "
                   "`rapp replay DIR` replays its RApp runs: docs/recordings.md)")
    a = p.parse_args(argv)
    settings = XmppSettings.from_env()
    role = {"store": _store, "platform": _platform, "core": _core}[a.role]
    asyncio.run(role(a, settings))
    return 0
