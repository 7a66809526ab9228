"""`rapp agent ROLE`: run one kind of agent on this machine against the configured XMPP server
(XmppSettings from RAPP_XMPP_*), until Ctrl-C. This is how a deployment spreads the system over
machines: Store and Platform on a server, one Core per robot (docs/deployment.md).

    rapp agent store --data /var/lib/rapp/store
    rapp agent platform --maps /var/lib/rapp/maps
    rapp agent core --robot nao --robot-id nao1 --owner alice --house house --seed 1
"""
from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal

from xmpp_server.settings import XmppSettings


async def _run_until_stopped(agents, cleanup=None) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    for a in agents:
        await a.start()
        print(f"{a.address} running ({type(a).__name__}); Ctrl-C stops it", flush=True)
    await stop.wait()
    for a in agents:
        with contextlib.suppress(Exception):
            await a.stop()
    if cleanup:
        cleanup()


async def _store(a, settings) -> None:
    from agents.store_agent import StoreAgent
    await _run_until_stopped([StoreAgent(a.name or "store", a.data, settings,
                                         require_signature=a.require_signature)])


async def _platform(a, settings) -> None:
    from agents.platform_agent import PlatformAgent
    from agents.services.context import ServiceState

    state = ServiceState()
    if a.maps:
        print(f"maps preloaded: {', '.join(state.preload_maps(a.maps)) or 'none'}")
    await _run_until_stopped([PlatformAgent(a.name or "platform", store=a.store, settings=settings,
                                            services_state=state)])


async def _core(a, settings) -> None:
    from agents.core_agent import CoreAgent
    from robots import RobotAPI, World

    world = World.from_file(a.house, seed=a.seed, rtf=a.rtf)
    api = RobotAPI(world.add_robot(a.robot))
    robot_id = a.robot_id or f"{a.robot}1"
    core = CoreAgent(a.name or f"core-{robot_id}", robot_id=robot_id, robot_type=a.robot, robot_api=api,
                     owner=a.owner, platform=a.platform, store=a.store, user=a.owner,
                     password=a.password or f"{a.owner}-pw", settings=settings)
    await _run_until_stopped([core], cleanup=world.close)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="rapp agent", description=__doc__.split("\n\n")[0])
    p.add_argument("role", choices=["store", "platform", "core"])
    p.add_argument("--name", help="the agent's account name (default: store / platform / core-ROBOT_ID)")
    p.add_argument("--store", default="store", help="the Store Agent's name or JID")
    p.add_argument("--platform", default="platform", help="the Platform Agent's name or JID")
    p.add_argument("--data", default="store-data", help="store: data directory (SQLite + blobs)")
    p.add_argument("--require-signature", action="store_true", help="store: refuse unsigned packages")
    p.add_argument("--maps", help="platform: directory of map_server YAML maps to preload")
    p.add_argument("--robot", choices=["nao", "elektron"], default="nao", help="core: robot model")
    p.add_argument("--robot-id")
    p.add_argument("--owner", default="owner", help="core: the user whose chat it listens to")
    p.add_argument("--password", help="core: the owner's Platform/Store password")
    p.add_argument("--house", default="small", help="core: simulated house (name or YAML file)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rtf", type=float, default=1.0, help="core: simulation real-time factor")
    a = p.parse_args(argv)
    settings = XmppSettings.from_env()
    role = {"store": _store, "platform": _platform, "core": _core}[a.role]
    asyncio.run(role(a, settings))
    return 0
